"""Moment of inertia Izz from a bifilar (two-string) torsional pendulum.

Two ways, both pure functions on numpy arrays (the CLI in :mod:`calibration.cli`
is a thin shell; the derivation is in docs/calibration.md):

- :func:`izz_from_times`: the paper's Equation 19, Izz = m g D^2 T^2 / (16 pi^2 h),
  on the mean period of stopwatch timings, with a first-order (GUM) propagation of
  the uncertainties of m, D, h and the spread of T, reported input by input.
- :func:`fit_swing_trace`: least-squares fit of the nonlinear large-angle model
  (Jardin & Mueller's restoring torque, viscous and quadratic damping, plus the
  kinetic energy of the body's rise) to a recorded yaw trace; Izz follows from the
  fitted small-amplitude frequency. Reported beside it: Eq. 19 on the period seen in
  the trace (a damped-sine fit) and the size of that amplitude correction.

Geometry: strings of length ``h`` (m), attached ``D`` (m) apart on the body and
directly above at the top, the body's centre of mass midway between them. Angles
in radians, times in seconds, SI throughout.

The model: with q = sqrt(1 - (D/h)^2 (1 - cos th) / 2), w0^2 = m g D^2 / (4 h Izz)
and mu = w0^2 D^2 / (4 g h) = m D^4 / (16 h^2 Izz),

    (1 + mu s^2/q^2) th'' = -w0^2 s/q - mu (s/q^2) (cos th + (D/h)^2 s^2 / (4 q^2)) th'^2
                            - c1 th' - c2 |th'| th'          (s = sin th)

``vertical_ke=False`` drops the mu terms (Jardin & Mueller's form). The small-angle
limit is th'' = -w0^2 th - c1 th', i.e. Equation 19 with T = 2 pi / w0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares

from common.errors import UserError

G_STANDARD = 9.80665  # m/s^2
MIN_OSCILLATIONS = 3  # full oscillations a trace must show


# --------------------------------------------------------------------------- Eq. 19


def izz_eq19(mass_kg, spacing_m, length_m, period_s, g: float = G_STANDARD):
    """Equation 19: Izz = m g D^2 T^2 / (16 pi^2 h), kg m^2 (broadcasts over arrays)."""
    return (np.asarray(mass_kg) * g * np.asarray(spacing_m) ** 2 * np.asarray(period_s) ** 2
            / (16.0 * math.pi**2 * np.asarray(length_m)))


def period_eq19(izz_kgm2, mass_kg, spacing_m, length_m, g: float = G_STANDARD):
    """Small-angle period T = 4 pi sqrt(h Izz / (m g D^2)), s (inverse of Eq. 19)."""
    return 4.0 * math.pi * np.sqrt(np.asarray(length_m) * np.asarray(izz_kgm2)
                                   / (np.asarray(mass_kg) * g * np.asarray(spacing_m) ** 2))


def check_geometry(mass_kg: float, spacing_m: float, length_m: float, g: float = G_STANDARD) -> None:
    """Refuse non-physical inputs with one UserError line."""
    for name, v in (("mass", mass_kg), ("string spacing D", spacing_m),
                    ("string length h", length_m), ("g", g)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise UserError(f"{name} must be a positive finite number, got {v!r}")


def period_from_times(times_s: Sequence[float], cycles: int) -> tuple[float, float, float]:
    """Mean period and its Type-A standard uncertainty from stopwatch timings.

    Args:
        times_s: (n,) time of ``cycles`` full oscillations per trial, s (n >= 2).
        cycles: full oscillations per timing (>= 1).
    Returns:
        (T, u_T, s_T): mean period, standard uncertainty of the mean s_T / sqrt(n) and
        the standard deviation of the single-trial period, all in s.
    """
    t = np.asarray(times_s, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise UserError(f"need at least 2 timings to estimate the spread of T, got {t.size}")
    if not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise UserError("timings must be positive finite numbers of seconds")
    if int(cycles) != cycles or cycles < 1:
        raise UserError(f"--cycles must be a whole number of oscillations >= 1, got {cycles!r}")
    per = t / cycles
    s = float(per.std(ddof=1))
    return float(per.mean()), s / math.sqrt(per.size), s


@dataclass
class IzzResult:
    """An Izz estimate with its standard uncertainty and the per-input budget.

    ``contributions_kgm2`` maps each input to |dIzz/dx| u(x) (kg m^2); their root sum
    of squares is ``izz_sigma_kgm2`` (inputs taken as uncorrelated).
    """

    izz_kgm2: float
    izz_sigma_kgm2: float
    method: str
    contributions_kgm2: dict[str, float]
    inputs: dict[str, Any] = field(default_factory=dict)
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (scalars only)."""
        d = {k: getattr(self, k) for k in ("izz_kgm2", "izz_sigma_kgm2", "method",
                                           "contributions_kgm2", "inputs", "details")}
        d["izz_rel_sigma"] = self.izz_sigma_kgm2 / abs(self.izz_kgm2) if self.izz_kgm2 else None
        return d


def eq19_budget(mass_kg: float, spacing_m: float, length_m: float, period_s: float, *,
                u_mass_kg: float = 0.0, u_spacing_m: float = 0.0, u_length_m: float = 0.0,
                u_period_s: float = 0.0, g: float = G_STANDARD, u_g: float = 0.0
                ) -> tuple[float, float, dict[str, float]]:
    """Equation 19 and its first-order uncertainty, input by input.

    Izz is a product of powers, so each relative contribution is the exponent times
    the input's relative uncertainty: m^1, g^1, D^2, T^2, h^-1.
    Returns (Izz, u(Izz), {input: contribution}) in kg m^2.
    """
    izz = float(izz_eq19(mass_kg, spacing_m, length_m, period_s, g))
    contrib = {
        "mass": izz * u_mass_kg / mass_kg,
        "spacing": izz * 2.0 * u_spacing_m / spacing_m,
        "length": izz * u_length_m / length_m,
        "period": izz * 2.0 * u_period_s / period_s,
        "g": izz * u_g / g,
    }
    sigma = math.sqrt(sum(v * v for v in contrib.values()))
    return izz, sigma, contrib


def izz_from_times(times_s: Sequence[float], cycles: int, mass_kg: float, spacing_m: float,
                   length_m: float, *, u_mass_kg: float = 0.0, u_spacing_m: float = 0.0,
                   u_length_m: float = 0.0, u_timing_s: float = 0.0, tare_izz_kgm2: float = 0.0,
                   u_tare_kgm2: float = 0.0, g: float = G_STANDARD, u_g: float = 0.0) -> IzzResult:
    """Izz by Equation 19 from stopwatch timings of ``cycles`` oscillations each.

    The period's uncertainty combines the spread of the trials (Type A, s/sqrt(n))
    with an optional per-timing reaction error ``u_timing_s`` (Type B, divided by
    cycles and sqrt(n)). ``tare_izz_kgm2`` (a fixture's inertia) is subtracted.
    """
    check_geometry(mass_kg, spacing_m, length_m, g)
    T, u_T_a, s_T = period_from_times(times_s, cycles)
    n = len(times_s)
    u_T_b = u_timing_s / cycles / math.sqrt(n)
    u_T = math.hypot(u_T_a, u_T_b)
    izz, _, contrib = eq19_budget(mass_kg, spacing_m, length_m, T, u_mass_kg=u_mass_kg,
                                  u_spacing_m=u_spacing_m, u_length_m=u_length_m,
                                  u_period_s=u_T, g=g, u_g=u_g)
    contrib["tare"] = float(u_tare_kgm2)
    net = izz - tare_izz_kgm2
    if net <= 0:
        raise UserError(f"the tare inertia {tare_izz_kgm2:g} kg m^2 is not smaller than the measured "
                        f"{izz:g} kg m^2")
    sigma = math.sqrt(sum(v * v for v in contrib.values()))
    per = np.asarray(times_s, float) / cycles
    return IzzResult(
        izz_kgm2=net, izz_sigma_kgm2=sigma, method="eq19-times", contributions_kgm2=contrib,
        inputs=dict(mass_kg=mass_kg, spacing_m=spacing_m, length_m=length_m, g=g, cycles=cycles,
                    times_s=[float(x) for x in times_s], u_mass_kg=u_mass_kg,
                    u_spacing_m=u_spacing_m, u_length_m=u_length_m, u_timing_s=u_timing_s,
                    tare_izz_kgm2=tare_izz_kgm2, u_tare_kgm2=u_tare_kgm2),
        details=dict(period_s=T, u_period_s=u_T, u_period_typeA_s=u_T_a, period_std_s=s_T,
                     n_trials=n, izz_gross_kgm2=izz,
                     worst_trial_dev=float(np.max(np.abs(per - np.median(per))) / np.median(per))),
    )


# ------------------------------------------------------------------ nonlinear model


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


def _rk4_grid(th: float, om: float, dt: float, n: int, w2: float, c1: float, c2: float,
              r2: float, mu: float) -> tuple[list[float], list[float], list[float]]:
    sin, cos, sqrt = math.sin, math.cos, math.sqrt

    def acc(x: float, v: float) -> float:
        s = sin(x)
        c = cos(x)
        q2 = 1.0 - 0.5 * r2 * (1.0 - c)
        if q2 <= 0.0:
            raise FloatingPointError
        num = w2 * s / sqrt(q2) + c1 * v + c2 * abs(v) * v
        if mu:
            num += mu * s / q2 * (c + 0.25 * r2 * s * s / q2) * v * v
            return -num / (1.0 + mu * s * s / q2)
        return -num

    ths, oms, acs = [th], [om], [acc(th, om)]
    h2, h6 = 0.5 * dt, dt / 6.0
    for _ in range(n):
        k1x, k1v = om, acs[-1]
        k2x, k2v = om + h2 * k1v, acc(th + h2 * k1x, om + h2 * k1v)
        k3x, k3v = om + h2 * k2v, acc(th + h2 * k2x, om + h2 * k2v)
        k4x, k4v = om + dt * k3v, acc(th + dt * k3x, om + dt * k3v)
        th += h6 * (k1x + 2 * k2x + 2 * k3x + k4x)
        om += h6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        ths.append(th)
        oms.append(om)
        acs.append(acc(th, om))
    return ths, oms, acs


def _hermite(t: np.ndarray, t0: float, dt: float, y: np.ndarray, dy: np.ndarray) -> np.ndarray:
    u = (t - t0) / dt
    i = np.clip(np.floor(u).astype(int), 0, len(y) - 2)
    s = u - i
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * y[i] + (s3 - 2 * s2 + s) * dt * dy[i]
            + (-2 * s3 + 3 * s2) * y[i + 1] + (s3 - s2) * dt * dy[i + 1])


def model_theta(t: np.ndarray, theta0: float, omega_init: float, omega0_sq: float, c1: float,
                c2: float, spacing_m: float, length_m: float, g: float = G_STANDARD,
                vertical_ke: bool = True, steps_per_period: int = 48) -> np.ndarray:
    """Model theta (rad) at times t (s, increasing, from t[0]) by RK4 + Hermite interpolation."""
    r2, mu = _coeffs(omega0_sq, spacing_m, length_m, g, vertical_ke)
    span = float(t[-1] - t[0])
    dt_max = 2.0 * math.pi / math.sqrt(max(omega0_sq, 1e-12)) / steps_per_period
    n = max(1, int(math.ceil(span / dt_max)))
    dt = span / n if span > 0 else 1.0
    ths, oms, _ = _rk4_grid(theta0, omega_init, dt, n, omega0_sq, c1, c2, r2, mu)
    return _hermite(np.asarray(t) - t[0], 0.0, dt, np.asarray(ths), np.asarray(oms))


# ------------------------------------------------------------------ trace analysis


def noise_sigma(y: np.ndarray) -> float:
    """Robust white-noise sigma from second differences (the signal is smooth)."""
    d2 = np.diff(y, 2)
    if d2.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def count_half_swings(y: np.ndarray, band: float) -> int:
    """Crossings of the mean with hysteresis +-band (two per full oscillation)."""
    state = 0
    n = 0
    for v in y:
        s = 1 if v > band else (-1 if v < -band else 0)
        if s and s != state:
            if state:
                n += 1
            state = s
    return n


@dataclass
class DampedSine:
    """Linear fit psi = off + exp(-sigma t) (a cos wd t + b sin wd t) (t from t[0])."""

    offset_rad: float
    sigma_per_s: float
    omega_d: float
    a: float
    b: float
    omega_d_sigma: float

    @property
    def period_s(self) -> float:
        return 2.0 * math.pi / self.omega_d

    def __call__(self, t: np.ndarray) -> np.ndarray:
        tt = t - t[0]
        e = np.exp(-self.sigma_per_s * tt)
        return self.offset_rad + e * (self.a * np.cos(self.omega_d * tt)
                                      + self.b * np.sin(self.omega_d * tt))


def fit_damped_sine(t: np.ndarray, psi: np.ndarray) -> DampedSine:
    """Fit a linearly damped sinusoid (the small-angle model) to a yaw trace."""
    tt = t - t[0]
    off0 = float(np.median(psi))
    y = psi - off0
    # frequency guess: FFT peak on a uniform resampling
    dt = float(np.median(np.diff(t)))
    grid = np.arange(0.0, tt[-1], dt)
    yg = np.interp(grid, tt, y)
    nfft = 1 << int(math.ceil(math.log2(max(len(grid), 2) * 8)))
    spec = np.abs(np.fft.rfft((yg - yg.mean()) * np.hanning(len(yg)), nfft))
    freqs = np.fft.rfftfreq(nfft, dt)
    spec[freqs < 1.5 / tt[-1]] = 0.0
    w = 2 * math.pi * float(freqs[int(np.argmax(spec))])
    amp = float(np.sqrt(2.0) * np.std(y))

    def res(p):
        o, sg, wd, a, b = p
        e = np.exp(-sg * tt)
        return o + e * (a * np.cos(wd * tt) + b * np.sin(wd * tt)) - y

    # start phase from a linear solve at the guessed frequency
    A = np.column_stack([np.ones_like(tt), np.cos(w * tt), np.sin(w * tt)])
    o, a, b = np.linalg.lstsq(A, y, rcond=None)[0]
    r = least_squares(res, [o, 0.0, w, a if amp else 0.0, b], method="lm", x_scale="jac")
    o, sg, wd, a, b = r.x
    dof = max(1, len(y) - 5)
    s2 = float(r.fun @ r.fun) / dof
    try:
        cov = np.linalg.inv(r.jac.T @ r.jac) * s2
        wsig = float(math.sqrt(max(cov[2, 2], 0.0)))
    except np.linalg.LinAlgError:
        wsig = float("nan")
    if wd < 0:
        wd, b = -wd, -b
    return DampedSine(off0 + float(o), float(sg), float(wd), float(a), float(b), wsig)


def check_trace(t: np.ndarray, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Validate a yaw trace; returns (t, unwrapped psi, noise sigma, half swings).

    Refuses (UserError) fewer than 20 samples, non-increasing time and a trace that
    does not show at least MIN_OSCILLATIONS full oscillations above the noise.
    """
    t = np.asarray(t, float)
    psi = np.asarray(psi, float)
    if t.shape != psi.shape or t.ndim != 1:
        raise UserError("time and yaw must be 1-D arrays of equal length")
    if t.size < 20:
        raise UserError(f"the trace has {t.size} samples; need at least 20")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(psi))):
        raise UserError("the trace holds non-finite values")
    if np.any(np.diff(t) <= 0):
        raise UserError("trace time does not strictly increase")
    psi = np.unwrap(psi)
    sig = noise_sigma(psi)
    y = psi - np.median(psi)
    band = max(3.0 * sig, 0.05 * float(np.percentile(np.abs(y), 95)), 1e-9)
    half = count_half_swings(y, band)
    if half < 2 * MIN_OSCILLATIONS:
        raise UserError(
            f"the trace does not oscillate: {half / 2:g} full oscillation(s) above the noise "
            f"(sigma {math.degrees(sig):.2g} deg); need at least {MIN_OSCILLATIONS}")
    return t, psi, sig, half


@dataclass
class TraceFit(IzzResult):
    """Result of :func:`fit_swing_trace` (an :class:`IzzResult` with the curves).

    ``t``, ``psi``, ``psi_fit`` (N,) hold the data and the fitted model for plots.
    """

    t: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    psi: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    psi_fit: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    psi_small: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)


def _w2_guess(w2_seen: float, amp: float, spacing_m: float, length_m: float, g: float,
              vertical_ke: bool) -> float:
    """w0^2 whose model swing at amplitude ``amp`` has the frequency seen (start value)."""
    if amp <= 0 or 0.5 * (spacing_m / length_m) ** 2 * (1 - math.cos(min(amp, math.pi))) >= 0.9:
        return w2_seen
    T = 2 * math.pi / math.sqrt(w2_seen)
    tq = np.linspace(0.0, 0.6 * T, 400)
    th = model_theta(tq, amp, 0.0, w2_seen, 0.0, 0.0, spacing_m, length_m, g, vertical_ke)
    k = int(np.argmax(th < 0))
    if k == 0:
        return w2_seen
    t_zero = tq[k - 1] + (tq[k] - tq[k - 1]) * th[k - 1] / (th[k - 1] - th[k])
    ratio = (T / 4) / t_zero  # model frequency at this amplitude / w0
    return w2_seen / ratio**2


def fit_swing_trace(t_s, psi_rad, mass_kg: float, spacing_m: float, length_m: float, *,
                    u_mass_kg: float = 0.0, u_spacing_m: float = 0.0, u_length_m: float = 0.0,
                    tare_izz_kgm2: float = 0.0, u_tare_kgm2: float = 0.0,
                    g: float = G_STANDARD, u_g: float = 0.0, vertical_ke: bool = True) -> TraceFit:
    """Fit the nonlinear bifilar model to a yaw trace and return Izz with its budget.

    Args:
        t_s: (N,) frame times, s (strictly increasing; gaps allowed).
        psi_rad: (N,) yaw, rad (may be wrapped; the equilibrium yaw is fitted).
        mass_kg, spacing_m, length_m: m, D, h of the pendulum (with u_* uncertainties).
    Fitted: ln w0^2, c1, c2, yaw offset, initial angle and rate. Izz = m g D^2/(4 h w0^2).
    The fit term of the budget is the covariance s^2 (J^T J)^-1 of ln w0^2 (white
    noise assumed); D, h and g also move the fitted w0^2 (through D/h and the rise
    term), which is included by linearising the fit around its optimum.
    """
    check_geometry(mass_kg, spacing_m, length_m, g)
    t, psi, sig, half = check_trace(t_s, psi_rad)
    lin = fit_damped_sine(t, psi)
    tt = t - t[0]
    # initial guess for the nonlinear fit from the damped sine
    env2 = (lin.a**2 + lin.b**2) * np.exp(-2 * lin.sigma_per_s * tt)
    w2_0 = _w2_guess(lin.omega_d**2, math.sqrt(float(np.mean(env2))), spacing_m, length_m, g,
                     vertical_ke)
    th0 = lin.a
    om0 = -lin.sigma_per_s * lin.a + lin.omega_d * lin.b
    if 0.5 * (spacing_m / length_m) ** 2 * (1 - math.cos(min(abs(th0) * 1.5, math.pi))) >= 0.95:
        raise UserError("the swing is too large for this geometry: the strings would nearly reach "
                        "horizontal (check D and h)")

    def model(beta, D=spacing_m, h=length_m, gg=g):
        lw2, c1, c2, off, a0, v0 = beta
        return off + model_theta(t, a0, v0, math.exp(lw2), c1, c2, D, h, gg, vertical_ke)

    def res(beta):
        try:
            return model(beta) - psi
        except (FloatingPointError, OverflowError, ValueError):
            return np.full_like(psi, 1e3)

    beta0 = np.array([math.log(w2_0), 2 * lin.sigma_per_s, 0.0, lin.offset_rad, th0, om0])
    r = least_squares(res, beta0, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12)
    if not r.success:
        raise UserError(f"the bifilar fit did not converge ({r.message})")
    beta = r.x
    J = r.jac
    dof = max(1, len(psi) - len(beta))
    s2 = float(r.fun @ r.fun) / dof
    JtJ_inv = np.linalg.pinv(J.T @ J)
    cov = JtJ_inv * s2
    w2 = math.exp(beta[0])
    izz = mass_kg * g * spacing_m**2 / (4.0 * length_m * w2)

    # total sensitivity of ln Izz to D, h, g: direct + through the refitted ln w0^2
    def dlnw2(key: str, val: float) -> float:
        dv = val * 1e-4
        kw_p = {"D": spacing_m, "h": length_m, "gg": g}
        kw_m = dict(kw_p)
        kw_p[key] = val + dv
        kw_m[key] = val - dv
        Jp = (model(beta, **kw_p) - model(beta, **kw_m)) / (2 * dv)
        dbeta = -JtJ_inv @ (J.T @ Jp)
        return float(dbeta[0])

    sens = {  # d ln Izz / d x
        "mass": 1.0 / mass_kg,
        "spacing": 2.0 / spacing_m - dlnw2("D", spacing_m),
        "length": -1.0 / length_m - dlnw2("h", length_m),
        "g": 1.0 / g - dlnw2("gg", g),
    }
    contrib = {
        "fit": izz * math.sqrt(max(cov[0, 0], 0.0)),
        "mass": abs(izz * sens["mass"] * u_mass_kg),
        "spacing": abs(izz * sens["spacing"] * u_spacing_m),
        "length": abs(izz * sens["length"] * u_length_m),
        "g": abs(izz * sens["g"] * u_g),
        "tare": float(u_tare_kgm2),
    }
    sigma = math.sqrt(sum(v * v for v in contrib.values()))
    net = izz - tare_izz_kgm2
    if net <= 0:
        raise UserError(f"the tare inertia {tare_izz_kgm2:g} kg m^2 is not smaller than the measured "
                        f"{izz:g} kg m^2")
    izz_small = float(izz_eq19(mass_kg, spacing_m, length_m, lin.period_s, g))
    psi_fit = model(beta)
    resid = psi - psi_fit
    amp = np.abs(psi_fit - beta[3])
    n_first = max(1, int(np.searchsorted(tt, 2 * math.pi / math.sqrt(w2))))
    details = dict(
        omega0_rad_s=math.sqrt(w2), period0_s=2 * math.pi / math.sqrt(w2),
        c1_per_s=float(beta[1]), c2_per_rad=float(beta[2]),
        k1_nms=float(beta[1]) * izz, k2_nms2=float(beta[2]) * izz,
        yaw_offset_rad=float(beta[3]), theta_start_rad=float(beta[4]),
        amplitude_start_deg=math.degrees(float(amp[:n_first].max())),
        amplitude_end_deg=math.degrees(float(amp[-n_first:].max())),
        residual_rms_deg=math.degrees(float(np.sqrt(np.mean(resid**2)))),
        noise_sigma_deg=math.degrees(sig), n_samples=int(len(t)), n_oscillations=half / 2,
        duration_s=float(tt[-1]), vertical_ke=vertical_ke,
        trace_period_s=lin.period_s, izz_small_angle_kgm2=izz_small - tare_izz_kgm2,
        amplitude_correction=izz / izz_small - 1.0,
        sensitivities_dlnizz={k: float(v) for k, v in sens.items()},
        izz_gross_kgm2=izz, nfev=int(r.nfev),
    )
    return TraceFit(
        izz_kgm2=net, izz_sigma_kgm2=sigma, method="bifilar-trace-fit", contributions_kgm2=contrib,
        inputs=dict(mass_kg=mass_kg, spacing_m=spacing_m, length_m=length_m, g=g,
                    u_mass_kg=u_mass_kg, u_spacing_m=u_spacing_m, u_length_m=u_length_m,
                    tare_izz_kgm2=tare_izz_kgm2, u_tare_kgm2=u_tare_kgm2),
        details=details, t=t, psi=psi, psi_fit=psi_fit, psi_small=lin(t),
    )


# ----------------------------------------------------------------------- for the demo


@dataclass
class SwingDemo:
    """A simulated swing and what the trace fit and Eq. 19 made of it."""

    truth: Pendulum
    fit: TraceFit
    izz_error_rel: float
    small_angle_error_rel: float


def swing_and_estimate(mass_kg: float, izz_kgm2: float, *, spacing_m: float = 0.10,
                       length_m: float = 1.0, release_deg: float = 20.0, duration_s: float = 30.0,
                       rate_hz: float = 120.0, noise_deg: float = 1.0, c1: float = 0.004,
                       c2: float = 0.01, seed: int | None = 0, u_mass_kg: float = 0.0,
                       u_spacing_m: float = 0.0, u_length_m: float = 0.0) -> SwingDemo:
    """Simulate a bifilar swing of a body with known m and Izz, and estimate Izz from it.

    For the demo: returns the truth, the trace fit (``fit.izz_kgm2``, ``fit.izz_sigma_kgm2``,
    ``fit.details['izz_small_angle_kgm2']``) and both relative errors.
    """
    p = Pendulum(mass_kg, izz_kgm2, spacing_m, length_m, c1=c1, c2=c2)
    t, psi = simulate_trace(p, release_deg=release_deg, duration_s=duration_s, rate_hz=rate_hz,
                            noise_deg=noise_deg, seed=seed)
    fit = fit_swing_trace(t, psi, mass_kg, spacing_m, length_m, u_mass_kg=u_mass_kg,
                          u_spacing_m=u_spacing_m, u_length_m=u_length_m)
    return SwingDemo(p, fit, fit.izz_kgm2 / izz_kgm2 - 1.0,
                     fit.details["izz_small_angle_kgm2"] / izz_kgm2 - 1.0)

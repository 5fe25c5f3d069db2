"""Izz from a recorded swing: the nonlinear bifilar model fitted to a yaw trace.

:func:`fit_swing_trace` fits the large-angle model (:mod:`calibration.swing.bifilar_model`:
Jardin & Mueller's restoring torque, viscous and quadratic damping, the kinetic energy
of the body's rise) by least squares; Izz follows from the fitted small-amplitude
frequency, with its budget (fit covariance, m, D, h, g, tare). Reported beside it:
Eq. 19 on the period seen in the trace (:func:`fit_damped_sine`) and the size of that
amplitude correction. :func:`check_trace` refuses traces that do not oscillate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from calibration.swing.bifilar_eq19 import (
    G_STANDARD,
    IzzResult,
    check_geometry,
    geometry_warnings,
    izz_eq19,
)
from calibration.swing.bifilar_model import model_theta
from common.errors import UserError

MIN_OSCILLATIONS = 3  # full oscillations a trace must show


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
    return check_signal(t, psi)


def check_signal(t: np.ndarray, y: np.ndarray, *, angle: bool = True, unit: str = "deg"
                 ) -> tuple[np.ndarray, np.ndarray, float, int]:
    """:func:`check_trace` for any swing signal: a yaw in rad (``angle``: unwrapped, noise
    quoted in degrees) or a rate, pixel or count trace (kept as is, noise in ``unit``)."""
    t = np.asarray(t, float)
    psi = np.asarray(y, float)
    if t.shape != psi.shape or t.ndim != 1:
        raise UserError(f"time and {'yaw' if angle else 'signal'} must be 1-D arrays of equal length")
    if t.size < 20:
        raise UserError(f"the trace has {t.size} samples; need at least 20")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(psi))):
        raise UserError("the trace holds non-finite values")
    if np.any(np.diff(t) <= 0):
        raise UserError("trace time does not strictly increase")
    if angle:
        psi = np.unwrap(psi)
    sig = noise_sigma(psi)
    y0 = psi - np.median(psi)
    band = max(3.0 * sig, 0.05 * float(np.percentile(np.abs(y0), 95)), 1e-9)
    half = count_half_swings(y0, band)
    if half < 2 * MIN_OSCILLATIONS:
        shown = f"{math.degrees(sig):.2g} deg" if angle else f"{sig:.2g} {unit}"
        raise UserError(
            f"the trace does not oscillate: {half / 2:g} full oscillation(s) above the noise "
            f"(sigma {shown}); need at least {MIN_OSCILLATIONS}")
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


def _trace_warnings(details: dict) -> list[str]:
    """A swing of more than 90 deg or residuals of tens of degrees: yaw not in radians?"""
    amp = float(details.get("amplitude_start_deg", 0.0))
    rms = float(details.get("residual_rms_deg", 0.0))
    if amp > 90.0 or rms > 10.0:
        return [f"the trace swings {amp:.3g} deg with residuals of {rms:.3g} deg rms: yaw in "
                "degrees instead of radians? another body's poses?"]
    return []


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
        c1_sigma_per_s=math.sqrt(max(cov[1, 1], 0.0)), c2_sigma_per_rad=math.sqrt(max(cov[2, 2], 0.0)),
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
        warnings=geometry_warnings(mass_kg, spacing_m, length_m, izz) + _trace_warnings(details),
    )

"""Izz from any swing recording, with fits that say when they do not fit.

:func:`fit_swing` takes a trace of a bifilar or trifilar swing (:class:`Suspension`) as
one of three signals:

- ``"angle"``: a yaw in rad (mocap poses, or a trace times ``--trace-scale``);
- ``"rate"``: a gyro's yaw rate in rad/s, fitted as the derivative of the large-angle
  model with the gyro's bias and linear drift as parameters (never integrated);
- ``"signal"``: any value proportional to the angle with unknown offset and gain
  (pixels, a laser spot, encoder counts): only the period is fitted (a damped sine, which
  is scale-free); the large-angle correction it cannot see goes into the uncertainty,
  for a swing between 0 and ``amplitude_max_deg`` (:data:`AMPLITUDE_MAX_DEG`).

Every fit is bounded least squares with non-negative damping, an offset (bias) and a
linear drift, and a second mode (the body's sway at about sqrt(g/L), or another) when
one is found in the residual (:data:`MODE2_CHI2_DROP`). When the final residual's rms
is more than :data:`NOISE_LIMIT` times the sensor noise (the robust spread of the
residual's second differences), the output says that the model does not describe the
trace, and the value falls back to the period method (Eq. 19 or its trifilar twin on
the damped-sine period) with the difference between the methods in its sigma.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.suspension import Suspension
from calibration.swing.bifilar_eq19 import IzzResult
from calibration.swing.bifilar_fit import (
    _w2_guess,
    check_signal,
    fit_damped_sine,
    fit_swing_trace,
    noise_sigma,
)
from calibration.swing.lsq import (
    MAIN_BAND,
    LsqFit,
    find_second_mode,
    fit_model,
    min_mode_omega,
    name_second_mode,
)
from calibration.swing.signal_model import SignalModel, angle_start_from_damped_sine
from common.errors import UserError

NOISE_LIMIT = 3.0
"""Residual rms / sensor noise above which the model is said not to describe the trace."""
MODE2_CHI2_DROP = 50.0
"""A second mode is kept when it lowers the residual sum of squares by this many noise
variances (4 parameters: a 1e-9 chance of keeping one in white noise)."""
AMPLITUDE_MAX_DEG = 15.0
"""Largest swing assumed for a trace without an angle scale (bifilar and trifilar swings
are released at 5-20 deg; a trace's rms amplitude is below its release angle)."""
AT_BOUND = 1e-6
"""A damping coefficient below this (1/s or 1/rad) is reported as held at its bound 0."""
NONLINEAR_MAX_NFEV = 60
"""The large-angle fit converges in 5-20 evaluations from the damped sine's start; a trace
it cannot describe is not worth more (the residual check then reports it)."""
SIGNALS = {"angle": ("yaw", "rad"), "rate": ("yaw rate", "rad/s"), "signal": ("trace", "units")}


@dataclass
class SwingFit(IzzResult):
    """:class:`IzzResult` of :func:`fit_swing`, with the data and fitted curves for plots:
    ``y`` the trace, ``y_fit`` the reported model, ``y_period`` the damped-sine fit."""

    t: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    y: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    y_fit: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    y_period: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d["warnings"] = list(self.warnings)
        return d


def _linear_fits(t, y, rate: bool, curved: bool, mode2: bool) -> tuple[LsqFit, LsqFit]:
    """The damped sine with offset and drift (and, ``curved``, a sensor curvature when it is
    worth it); then the same with a second mode when one is worth it (else the same fit)."""
    lin = fit_damped_sine(t, y)
    f0 = fit_model(SignalModel(rate, True, False), t, y,
                   [2 * math.log(lin.omega_d), max(lin.sigma_per_s, 0.0), lin.a, lin.b,
                    lin.offset_rad, 0.0])
    if curved:
        fc = fit_model(SignalModel(rate, True, False, curved=True), t, y, [*f0.beta, 0.0, 0.0])
        if f0.ssr - fc.ssr >= MODE2_CHI2_DROP * f0.noise**2:
            f0 = fc
    if not mode2:
        return f0, f0
    cand = find_second_mode(t, f0.resid, math.exp(0.5 * f0.beta[0]))
    if cand is None:
        return f0, f0
    a2, b2, w2 = cand
    m1 = SignalModel(rate, True, True, curved=f0.model.curved, mode2_omega_min=min_mode_omega(t))
    b = list(f0.beta)
    f1 = fit_model(m1, t, y, [*b[:6], a2, b2, 2 * math.log(w2), 0.0, *b[6:]])
    if f0.ssr - f1.ssr < MODE2_CHI2_DROP * f0.noise**2:
        return f0, f0
    # a "second mode" the fit moved onto the swing's own frequency is the swing itself (its
    # amplitude or damping not quite the model's), not another mode
    w_main, w_2 = math.exp(0.5 * f1.beta[0]), math.exp(0.5 * f1.beta[8])
    if abs(w_2 - w_main) < MAIN_BAND * w_main:
        return f0, f0
    return f0, f1


def _nonlinear_fit(t, y, rate: bool, s: Suspension, lin: LsqFit, vertical_ke: bool) -> LsqFit:
    """The large-angle model started from the damped sine ``lin`` (and its second mode)."""
    lnwd2, sg, a, b, n0, n1 = lin.beta[:6]
    th0, om0 = angle_start_from_damped_sine(lnwd2, sg, a, b, rate)
    amp = math.hypot(th0, om0 / math.exp(0.5 * lnwd2))
    if 0.5 * (s.spacing_m / s.length_m) ** 2 * (1 - math.cos(min(amp * 1.5, math.pi))) >= 0.95:
        raise UserError("the swing is too large for this geometry: the strings would nearly reach "
                        f"horizontal (check the {s.arm_key} and the length; a rate in deg/s "
                        "given as rad/s?)")
    w2 = _w2_guess(math.exp(lnwd2), amp, s.spacing_m, s.length_m, s.g, vertical_ke)
    model = SignalModel(rate, False, lin.model.mode2, s.spacing_m, s.length_m, s.g, vertical_ke,
                        mode2_omega_min=lin.model.mode2_omega_min)
    beta0 = [math.log(w2), 2 * sg, 1e-6, th0, om0, n0, n1, *lin.beta[6:10]]
    return fit_model(model, t, y, beta0, max_nfev=NONLINEAR_MAX_NFEV)


def _sensitivities(f: LsqFit, t: np.ndarray, s: Suspension) -> dict[str, float]:
    """d ln Izz / d x for m, D (per metre of the equivalent spacing), h, g: the direct
    exponents of m g D^2 / (h w0^2) plus, for the large-angle model, the shift of the
    refitted ln w0^2 (linearised around the optimum)."""
    sens = {"mass": 1 / s.mass_kg, "spacing": 2 / s.spacing_m, "length": -1 / s.length_m,
            "g": 1 / s.g}
    if f.model.linear:
        return sens
    for key, val in (("spacing", s.spacing_m), ("length", s.length_m), ("g", s.g)):
        dv = val * 1e-4
        kw = {"spacing": "spacing_m", "length": "length_m", "g": "g"}[key]
        d = (f.model(f.beta, t, **{kw: val + dv}) - f.model(f.beta, t, **{kw: val - dv})) / (2 * dv)
        d = np.where(f.free, f.jtj_inv @ (f.jac.T @ d), 0.0)
        sens[key] -= float(-d[0])
    return sens


def _budget(izz: float, f: LsqFit, sens: dict[str, float], s: Suspension) -> dict[str, float]:
    return {
        "fit": izz * f.sigma(f.model.names[0]) * (f.ratio if f.ratio > NOISE_LIMIT else 1.0),
        "mass": abs(izz * sens["mass"] * s.u_mass_kg),
        s.arm_key: abs(izz * sens["spacing"] * s.u_spacing_m),
        "length": abs(izz * sens["length"] * s.u_length_m),
        "g": abs(izz * sens["g"] * s.u_g),
        "tare": float(s.u_tare_kgm2),
    }


def amplitude_correction(s: Suspension, omega_sq: float, amplitude_rad: float,
                         vertical_ke: bool = True) -> float:
    """Izz(large-angle) / Izz(small-angle formula) - 1 for a swing of this amplitude (< 0:
    the swing lengthens the period, so the small-angle formula reads high)."""
    w2 = _w2_guess(omega_sq, amplitude_rad, s.spacing_m, s.length_m, s.g, vertical_ke)
    return omega_sq / w2 - 1.0


def fit_swing(t_s, y, signal: str, s: Suspension, *, vertical_ke: bool = True,
              mode2: bool = True, amplitude_max_deg: float = AMPLITUDE_MAX_DEG) -> SwingFit:
    """Izz of the body on ``s`` from a trace: see the module docstring.

    Args:
        t_s: (N,) sample times, s (strictly increasing; gaps allowed).
        y: (N,) the trace: yaw (rad, "angle"), yaw rate (rad/s, "rate") or any unit ("signal").
        signal: "angle", "rate" or "signal".
        mode2: look for (and model) a second mode.
    Returns a :class:`SwingFit`: ``izz_kgm2`` and ``izz_sigma_kgm2`` the recommended value
    and its total sigma, ``method`` the method that gave it, ``warnings``.
    """
    if signal not in SIGNALS:
        raise ValueError(f"signal must be one of {tuple(SIGNALS)}")
    s.check()
    what, unit = SIGNALS[signal]
    t, yv, _, half = check_signal(t_s, y, angle=signal == "angle", unit=unit)
    rate = signal == "rate"
    f0, lin = _linear_fits(t, yv, rate, signal == "signal", mode2)
    period = 2 * math.pi / math.exp(0.5 * lin.beta[0])
    izz_period = s.izz_small_angle(period)
    sens_lin = _sensitivities(lin, t, s)
    warnings: list[str] = []
    contrib_period = _budget(izz_period, lin, sens_lin, s)
    nl = None if signal == "signal" else _nonlinear_fit(t, yv, rate, s, lin, vertical_ke)
    if nl is None:  # scale-free: the period, and the amplitude correction it cannot see
        primary, izz, contrib, method = lin, izz_period, dict(contrib_period), "signal-fit"
        corr = amplitude_correction(s, math.exp(lin.beta[0]), math.radians(amplitude_max_deg),
                                    vertical_ke)
        contrib["amplitude"] = abs(izz * corr) / math.sqrt(3.0)
        amp_note = {"amplitude_assumed_deg": [0.0, amplitude_max_deg],
                    "amplitude_correction_bound": corr}
    else:
        primary, method = nl, ("trace-fit" if signal == "angle" else "rate-fit")
        izz = s.mass_kg * s.g * s.spacing_m**2 / (4 * s.length_m * math.exp(nl.beta[0]))
        contrib = _budget(izz, nl, _sensitivities(nl, t, s), s)
        amp_note = {}
    ratio = primary.ratio
    if ratio > NOISE_LIMIT:
        warnings.append(
            f"the model does not describe the trace: residual rms {primary.rms:.3g} {unit} is "
            f"{ratio:.1f} times the sensor noise {primary.noise:.3g} {unit} (from the residual's "
            f"second differences; limit {NOISE_LIMIT:g})"
            + ("" if nl is None else "; Izz falls back to the period method, its sigma covers "
               "the difference between the methods"))
        if nl is not None:
            contrib = dict(contrib_period, model=abs(izz - izz_period))
            izz, method, primary = izz_period, "period", lin
    net = izz - s.tare_izz_kgm2
    if net <= 0:
        raise UserError(f"the tare inertia {s.tare_izz_kgm2:g} kg m^2 is not smaller than the "
                        f"measured {izz:g} kg m^2")
    sigma = math.sqrt(sum(v * v for v in contrib.values()))
    details = _details(t, yv, signal, s, f0, lin, nl, primary, izz_period, half)
    details.update(amp_note, izz_gross_kgm2=izz)
    if lin.model.mode2:
        k = harmonic_of(details["second_mode"]["frequency_hz"], math.exp(0.5 * lin.beta[0]) / (2 * math.pi))
        if k is not None:  # the swing's own harmonic, not another mode: said in the details
            details["second_mode"]["name"] = (
                f"the swing's own harmonic {k} (a large or quadratically damped swing is no pure "
                f"sine), modelled as a sinusoid; not another mode")
            details["second_mode"]["harmonic"] = k
        else:
            warnings.append(f"a second mode is in the trace and was modelled: "
                            f"{details['second_mode']['name']}")
    return SwingFit(
        izz_kgm2=net, izz_sigma_kgm2=sigma, method=f"{s.kind}-{method}",
        contributions_kgm2=contrib, inputs={**s.inputs(), "signal": signal},
        details=details, warnings=s.warnings(izz) + warnings,
        t=t, y=yv, y_fit=primary.model(primary.beta, t), y_period=lin.model(lin.beta, t))


def _details(t, y, signal, s: Suspension, f0: LsqFit, lin: LsqFit, nl: LsqFit | None,
             primary: LsqFit, izz_period: float, half: int) -> dict[str, Any]:
    unit = SIGNALS[signal][1]
    tt = t - t[0]
    d: dict[str, Any] = {
        "signal": signal, "unit": unit, "n_samples": int(len(t)), "n_oscillations": half / 2,
        "duration_s": float(tt[-1]), "trace_period_s": 2 * math.pi / math.exp(0.5 * lin.beta[0]),
        "izz_period_kgm2": izz_period - s.tare_izz_kgm2,
        "izz_small_angle_kgm2": izz_period - s.tare_izz_kgm2,
        "residual_rms": primary.rms, "noise_sigma": primary.noise,
        "residual_to_noise": primary.ratio, "noise_limit": NOISE_LIMIT,
        "model_describes_trace": bool(primary.ratio <= NOISE_LIMIT),
        "offset": primary.value("n0"), "drift_per_s": primary.value("n1"),
        "period_damping_per_s": float(lin.beta[1]),
    }
    if nl is not None:
        w2 = math.exp(nl.beta[0])
        izz_nl = s.mass_kg * s.g * s.spacing_m**2 / (4 * s.length_m * w2)
        th = nl.model.swing_only(nl.beta, t)
        theta = th if signal == "angle" else np.cumsum(np.r_[0, np.diff(tt) * 0.5 * (th[1:] + th[:-1])])
        theta = theta - (0 if signal == "angle" else theta.mean())
        n_first = max(1, int(np.searchsorted(tt, 2 * math.pi / math.sqrt(w2))))
        d.update({
            "omega0_rad_s": math.sqrt(w2), "period0_s": 2 * math.pi / math.sqrt(w2),
            "izz_fit_kgm2": izz_nl - s.tare_izz_kgm2, "c1_per_s": float(nl.beta[1]),
            "c2_per_rad": float(nl.beta[2]), "k1_nms": float(nl.beta[1]) * izz_nl,
            "k2_nms2": float(nl.beta[2]) * izz_nl,
            "damping_at_bound": [n for n, fr, v in zip(nl.model.names[1:3], nl.free[1:3],
                                                       nl.beta[1:3], strict=True)
                                 if not fr or v < AT_BOUND],
            "amplitude_correction": izz_nl / izz_period - 1.0,
            "amplitude_start_deg": math.degrees(float(np.abs(theta[:n_first]).max())),
            "amplitude_end_deg": math.degrees(float(np.abs(theta[-n_first:]).max())),
            "fit_residual_to_noise": nl.ratio,
        })
    else:
        d["period0_s"] = d["trace_period_s"]
    if lin.model.curved:
        d["sensor_curvature"] = {"k2": lin.value("k2"), "k3": lin.value("k3")}
    if lin.model.mode2:
        w = math.exp(0.5 * lin.value("ln_w2sq"))
        d["second_mode"] = {
            "name": name_second_mode(w, s.sway_omega_rad_s), "frequency_hz": w / (2 * math.pi),
            "sway_frequency_hz": s.sway_omega_rad_s / (2 * math.pi),
            "amplitude": math.hypot(lin.value("a2"), lin.value("b2")),
            "damping_per_s": lin.value("s2_per_s"),
            "residual_to_noise_without": f0.ratio}
    return d


HARMONIC_TOLERANCE = 0.03
"""A second mode within this fraction of 2, 3, 4 or 5 times the swing's frequency is the
swing's own harmonic."""


def harmonic_of(f_hz: float, main_hz: float) -> int | None:
    """k when ``f_hz`` is within :data:`HARMONIC_TOLERANCE` of k times ``main_hz`` (k = 2..5)."""
    if not main_hz > 0:
        return None
    k = round(f_hz / main_hz)
    return k if 2 <= k <= 5 and abs(f_hz / (k * main_hz) - 1) < HARMONIC_TOLERANCE else None


REFIT_RATIO = 1.5
"""A bifilar yaw fit by :func:`calibration.swing.bifilar_fit.fit_swing_trace` is kept when its
damping is not negative beyond NEGATIVE_DAMPING_SIGMAS standard errors and its residual is
within this factor of the noise; otherwise the trace is refitted here (bounded damping,
drift, a second mode)."""
NEGATIVE_DAMPING_SIGMAS = 2.0


def fit_pose_trace(t_s, psi_rad, s: Suspension, *, vertical_ke: bool = True) -> IzzResult:
    """Izz from a yaw trace (rad): the bifilar trace fit of :mod:`calibration.swing.bifilar_fit`
    when it is physical and describes the trace, else :func:`fit_swing` on the angle (a
    trifilar always goes to :func:`fit_swing`). The result says which in ``details``."""
    if s.kind == "trifilar":
        return fit_swing(t_s, psi_rad, "angle", s, vertical_ke=vertical_ke)
    old = fit_swing_trace(t_s, psi_rad, s.mass_kg, s.arm_m, s.length_m, u_mass_kg=s.u_mass_kg,
                          u_spacing_m=s.u_arm_m, u_length_m=s.u_length_m,
                          tare_izz_kgm2=s.tare_izz_kgm2, u_tare_kgm2=s.u_tare_kgm2, g=s.g,
                          u_g=s.u_g, vertical_ke=vertical_ke)
    resid = old.psi - old.psi_fit
    noise = noise_sigma(resid)
    ratio = float(np.sqrt(np.mean(resid**2))) / noise if noise > 0 else math.inf
    d = old.details
    negative = [k for k in ("c1_per_s", "c2_per_rad")
                if d[k] < -NEGATIVE_DAMPING_SIGMAS * d[k.replace("_per", "_sigma_per")]]
    reasons = [f"negative damping ({', '.join(negative)})"] if negative else []
    if ratio > REFIT_RATIO:
        reasons.append(f"residual {ratio:.1f} times the noise")
    if not reasons:
        d.update(residual_to_noise=ratio, noise_limit=NOISE_LIMIT, model_describes_trace=True)
        return old
    new = fit_swing(old.t, old.psi, "angle", s, vertical_ke=vertical_ke)
    new.details["refit_reason"] = (f"the unbounded fit without drift or second mode gave "
                                   f"{' and '.join(reasons)}")
    return new

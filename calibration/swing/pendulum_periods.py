"""The period of a swing from any trace proportional to its angle (a laser spot's pixel
coordinate, an encoder count, a yaw), scale-free: a fit of damped sines.

The trace is modelled as up to two damped sinusoids (the swing and a second mode, such as
the sway of the whole pendulum at sqrt(g/L)) plus an offset and a linear drift:

    y(t) = sum_k exp(-l_k t) (a_k sin(w_k t) + b_k cos(w_k t)) + c + d t

The frequencies start at the peaks of the trace's spectrum (Hann window, zero-padded FFT);
the second mode is fitted when its spectral peak is at least ``SECOND_MODE_MIN`` of the
first and apart from it. The fit is a variable projection: the nonlinear (w_k, l_k) by
Levenberg-Marquardt, the amplitudes, offset and drift solved linearly inside. The swing is
the mode with the larger amplitude. Its period's sigma is the covariance s^2 (J^T J)^-1 of
the full fit, inflated by the residual's integrated autocorrelation time (a coloured
residual holds fewer independent samples than it has rows).

Pure functions on arrays; nothing here reads files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.errors import UserError

SECOND_MODE_MIN = 0.05
"""A second spectral peak below this fraction of the first is not fitted."""


@dataclass(frozen=True)
class SwingPeriod:
    """The swing's period (s) and sigma; the second mode's, if fitted; fit diagnostics."""

    period_s: float
    period_sigma_s: float
    decay_per_s: float
    amplitude: float
    second_period_s: float | None
    second_amplitude: float | None
    residual_rms: float
    correlation_factor: float
    n_samples: int
    duration_s: float

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _spectral_peaks(t: np.ndarray, y: np.ndarray) -> list[tuple[float, float]]:
    """The two largest spectral peaks (frequency Hz, magnitude), the largest first."""
    dt = float(np.median(np.diff(t)))
    n = len(y)
    nfft = 1 << max(14, int(math.ceil(math.log2(16 * n))))
    spec = np.abs(np.fft.rfft((y - y.mean()) * np.hanning(n), nfft))
    f = np.fft.rfftfreq(nfft, dt)
    duration = t[-1] - t[0]
    lo = 2.0 / duration  # at least two cycles in the trace
    spec[f < lo] = 0.0
    # local maxima of the spectrum: a mode is a peak, not the shoulder of another's lobe
    peak = np.flatnonzero((spec[1:-1] > spec[:-2]) & (spec[1:-1] >= spec[2:])) + 1
    if peak.size == 0:
        raise UserError("the swing trace does not oscillate (no spectral peak)")
    order = peak[np.argsort(spec[peak])[::-1]]
    i = int(order[0])
    j = int(order[1]) if order.size > 1 else i
    return [(float(f[i]), float(spec[i])), (float(f[j]), float(spec[j]) if j != i else 0.0)]


def _basis(t: np.ndarray, theta: np.ndarray) -> np.ndarray:
    cols = [np.ones_like(t), t - t.mean()]
    for w, lam in theta.reshape(-1, 2):
        e = np.exp(-lam * (t - t[0]))
        cols += [e * np.sin(w * t), e * np.cos(w * t)]
    return np.column_stack(cols)


def _integrated_autocorrelation(r: np.ndarray) -> float:
    """1 + 2 sum rho_k up to the first non-positive lag: how many rows one independent
    residual spans (1 for white noise)."""
    r = r - r.mean()
    n = len(r)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(r, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[:n]
    if acf[0] <= 0:
        return 1.0
    rho = acf / acf[0]
    stop = np.argmax(rho[1:] <= 0) + 1 if np.any(rho[1:] <= 0) else n
    return max(1.0, float(1.0 + 2.0 * rho[1:stop].sum()))


def swing_period(t_s: np.ndarray, y: np.ndarray, modes: int | None = None) -> SwingPeriod:
    """The swing's period from a trace ``y`` (any unit) sampled at times ``t_s``.

    ``modes``: 1 or 2 damped sines (default: 2 when the spectrum shows a second peak of at
    least :data:`SECOND_MODE_MIN` of the first). A trace that is too short (fewer than 20
    samples or two cycles), not finite or not increasing in time is a UserError."""
    from scipy.optimize import least_squares

    t = np.asarray(t_s, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.shape != y.shape or t.ndim != 1 or len(t) < 20:
        raise UserError(f"a swing trace needs at least 20 samples of time and value, got {len(t)}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise UserError("the swing trace holds a value that is not a finite number")
    if np.any(np.diff(t) <= 0):
        raise UserError("the swing trace's times do not increase")
    if np.ptp(y) == 0:
        raise UserError("the swing trace is constant: it does not oscillate")
    peaks = _spectral_peaks(t, y)
    if modes is None:
        modes = 2 if peaks[1][1] >= SECOND_MODE_MIN * peaks[0][1] else 1
    if modes not in (1, 2):
        raise UserError(f"modes must be 1 or 2, got {modes}")
    theta0 = np.array([v for f, _ in peaks[:modes] for v in (2 * math.pi * f, 0.0)])
    scale = float(np.std(y)) or 1.0
    ys = (y - y.mean()) / scale

    def resid(theta):
        a = _basis(t, theta)
        coef, *_ = np.linalg.lstsq(a, ys, rcond=None)
        return a @ coef - ys

    sol = least_squares(resid, theta0, method="lm", x_scale="jac")
    theta = sol.x
    a = _basis(t, theta)
    coef, *_ = np.linalg.lstsq(a, ys, rcond=None)
    r = a @ coef - ys
    amps = [math.hypot(*coef[2 + 2 * k: 4 + 2 * k]) for k in range(modes)]
    main = int(np.argmax(amps))
    # full Jacobian over (theta, linear coefficients): numeric in theta, the basis in the rest
    eps = 1e-6 * np.maximum(1.0, np.abs(theta))
    jt = np.empty((len(t), len(theta)))
    for i in range(len(theta)):
        th = theta.copy()
        th[i] += eps[i]
        jt[:, i] = (_basis(t, th) @ coef - a @ coef) / eps[i]
    jac = np.column_stack([jt, a])
    dof = max(1, len(t) - jac.shape[1])
    s2 = float(r @ r) / dof
    tau = _integrated_autocorrelation(r)
    try:
        cov = np.linalg.inv(jac.T @ jac) * s2 * tau
    except np.linalg.LinAlgError:
        raise UserError("the swing trace does not determine a period (singular fit)") from None
    w, lam = theta[2 * main], theta[2 * main + 1]
    w_sigma = math.sqrt(max(cov[2 * main, 2 * main], 0.0))
    if not (w > 0 and math.isfinite(w)) or w * (t[-1] - t[0]) < 4 * math.pi:
        raise UserError("the swing trace does not oscillate (fewer than two cycles)")
    period = 2 * math.pi / abs(w)
    other = 1 - main if modes == 2 else None
    return SwingPeriod(
        period_s=period, period_sigma_s=period * w_sigma / abs(w), decay_per_s=float(lam),
        amplitude=amps[main] * scale,
        second_period_s=None if other is None else 2 * math.pi / abs(theta[2 * other]),
        second_amplitude=None if other is None else amps[other] * scale,
        residual_rms=math.sqrt(float(r @ r) / len(t)) * scale, correlation_factor=tau,
        n_samples=len(t), duration_s=float(t[-1] - t[0]))

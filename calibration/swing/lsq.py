"""Bounded least squares of a :class:`calibration.swing.signal_model.SignalModel`, and the search
for a second mode in what a fit leaves.

:func:`fit_model` runs a trust-region fit with the damping coefficients bounded at zero
and returns an :class:`LsqFit`: the parameters, their covariance s^2 (J^T J)^-1 over the
parameters not held at a bound, the residual, and how the residual compares with the
sensor's noise (:func:`calibration.swing.bifilar_fit.noise_sigma` of the residual: the robust
spread of its second differences, which a smooth misfit does not reach).
:func:`find_second_mode` looks for the strongest spectral peak of a residual away from the
swing's own frequency; :func:`name_second_mode` names it (the pendulum sway at sqrt(g/L)?).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from calibration.swing.bifilar_fit import noise_sigma
from calibration.swing.signal_model import SignalModel

MAIN_BAND = 0.12
"""A second-mode candidate must lie more than this fraction away from the swing frequency."""
SWAY_TOLERANCE = 0.15
"""A second mode within this fraction of sqrt(g/L) is named the pendulum sway."""


@dataclass
class LsqFit:
    """One fitted :class:`SignalModel` (``beta`` in the order of ``model.names``)."""

    model: SignalModel
    beta: np.ndarray
    cov: np.ndarray
    resid: np.ndarray
    jac: np.ndarray
    jtj_inv: np.ndarray
    free: np.ndarray
    nfev: int

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.resid**2)))

    @property
    def noise(self) -> float:
        """White-noise sigma of the sensor, from the residual's second differences."""
        return noise_sigma(self.resid)

    @property
    def ratio(self) -> float:
        """Residual rms / sensor noise: about 1 when the model describes the trace."""
        n = self.noise
        return self.rms / n if n > 0 else math.inf

    @property
    def ssr(self) -> float:
        return float(self.resid @ self.resid)

    def value(self, name: str) -> float:
        return float(self.beta[self.model.names.index(name)])

    def sigma(self, name: str) -> float:
        i = self.model.names.index(name)
        return float(math.sqrt(max(self.cov[i, i], 0.0)))


def fit_model(model: SignalModel, t: np.ndarray, y: np.ndarray, beta0, max_nfev: int = 200
              ) -> LsqFit:
    """Bounded least squares of ``model`` to (t, y) from ``beta0`` (clipped into the bounds),
    at most ``max_nfev`` evaluations besides the Jacobian's."""
    lo, hi = model.bounds()
    b0 = np.clip(np.asarray(beta0, float), lo, hi)
    big = 1e3 * (float(np.ptp(y)) + 1.0)

    def res(b):
        try:
            with np.errstate(all="ignore"):
                r = model(b, t) - y
        except (FloatingPointError, OverflowError, ValueError, ZeroDivisionError):
            return np.full_like(y, big)
        return r if np.all(np.isfinite(r)) else np.full_like(y, big)

    r = least_squares(res, b0, bounds=(lo, hi), method="trf", x_scale="jac", xtol=1e-12,
                      ftol=1e-12, gtol=1e-10, max_nfev=max_nfev)
    free = r.active_mask == 0
    J = r.jac
    dof = max(1, len(y) - int(free.sum()))
    s2 = float(r.fun @ r.fun) / dof
    inv = np.zeros((len(b0), len(b0)))
    Jf = J[:, free]
    inv[np.ix_(free, free)] = np.linalg.pinv(Jf.T @ Jf)
    return LsqFit(model, r.x, inv * s2, r.fun, J, inv, free, int(r.nfev))


def min_mode_omega(t: np.ndarray) -> float:
    """The lowest frequency (rad/s) a second mode may have: 1.5 cycles over the trace (a
    slower wander is drift, not a mode)."""
    return 2.0 * math.pi * 1.5 / float(t[-1] - t[0])


def find_second_mode(t: np.ndarray, resid: np.ndarray, omega_main: float
                     ) -> tuple[float, float, float] | None:
    """The strongest spectral peak of ``resid`` more than MAIN_BAND from ``omega_main`` and
    above 1.5 cycles per trace: (a2, b2, w2) of a sinusoid there (a linear solve), or None."""
    tt = t - t[0]
    dt = float(np.median(np.diff(tt)))
    grid = np.arange(0.0, tt[-1], dt)
    if grid.size < 16:
        return None
    rg = np.interp(grid, tt, resid)
    nfft = 1 << int(math.ceil(math.log2(grid.size * 8)))
    spec = np.abs(np.fft.rfft((rg - rg.mean()) * np.hanning(grid.size), nfft))
    w = 2.0 * math.pi * np.fft.rfftfreq(nfft, dt)
    spec[(w < min_mode_omega(t)) | (np.abs(w / omega_main - 1.0) < MAIN_BAND)] = 0.0
    spec[w > 0.4 * math.pi / dt] = 0.0  # above 0.2 of the sampling rate: noise
    if not np.any(spec > 0):
        return None
    w2 = float(w[int(np.argmax(spec))])
    A = np.column_stack([np.cos(w2 * tt), np.sin(w2 * tt), np.ones_like(tt)])
    a2, b2, _ = np.linalg.lstsq(A, resid, rcond=None)[0]
    return float(a2), float(b2), w2


def name_second_mode(omega_rad_s: float, sway_omega_rad_s: float) -> str:
    """'pendulum sway ...' when the mode is within SWAY_TOLERANCE of sqrt(g/L), else a
    neutral name that quotes where the sway would be."""
    f, fs = omega_rad_s / (2 * math.pi), sway_omega_rad_s / (2 * math.pi)
    if abs(omega_rad_s / sway_omega_rad_s - 1.0) < SWAY_TOLERANCE:
        return f"pendulum sway of the body on its strings at {f:.4g} Hz (sqrt(g/L)/2pi = {fs:.4g} Hz)"
    return (f"an unidentified second mode at {f:.4g} Hz (not the pendulum sway: sqrt(g/L)/2pi "
            f"= {fs:.4g} Hz)")

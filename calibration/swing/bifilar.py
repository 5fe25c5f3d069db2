"""Moment of inertia Izz from a bifilar (two-string) torsional pendulum.

Two ways, both pure functions on numpy arrays (the CLI in :mod:`tpods.cli.calibrate`
is a thin shell; the derivation is in docs/calibration.md):

- :func:`izz_from_times`: the paper's Equation 19, Izz = m g D^2 T^2 / (16 pi^2 h),
  on the mean period of stopwatch timings, with a first-order (GUM) propagation of
  the uncertainties of m, D, h and the spread of T, reported input by input.
- :func:`fit_swing_trace`: least-squares fit of the nonlinear large-angle model
  (Jardin & Mueller's restoring torque, viscous and quadratic damping, plus the
  kinetic energy of the body's rise) to a recorded yaw trace; Izz follows from the
  fitted small-amplitude frequency. Reported beside it: Eq. 19 on the period seen in
  the trace (a damped-sine fit) and the size of that amplitude correction.

Geometry, the model and its small-angle limit: :mod:`calibration.swing.bifilar_model`.

This module gathers them (import from here): Equation 19 and its budget in
:mod:`calibration.swing.bifilar_eq19`, the nonlinear model and its simulation in
:mod:`calibration.swing.bifilar_model`, the trace fit in :mod:`calibration.swing.bifilar_fit`; it
adds :func:`swing_and_estimate` (simulate a swing, estimate Izz from it) for the demo.
"""

from __future__ import annotations

from dataclasses import dataclass

from calibration.swing.bifilar_eq19 import (
    G_STANDARD,
    IzzResult,
    check_geometry,
    eq19_budget,
    izz_eq19,
    izz_from_times,
    period_eq19,
    period_from_times,
)
from calibration.swing.bifilar_fit import (
    MIN_OSCILLATIONS,
    DampedSine,
    TraceFit,
    check_trace,
    count_half_swings,
    fit_damped_sine,
    fit_swing_trace,
    noise_sigma,
)
from calibration.swing.bifilar_model import (
    Pendulum,
    model_theta,
    simulate_swing,
    simulate_trace,
    swing_accel,
    swing_energy,
)

__all__ = ["G_STANDARD", "MIN_OSCILLATIONS", "DampedSine", "IzzResult", "Pendulum", "SwingDemo",
           "TraceFit", "check_geometry", "check_trace", "count_half_swings", "eq19_budget",
           "fit_damped_sine", "fit_swing_trace", "izz_eq19", "izz_from_times", "model_theta",
           "noise_sigma", "period_eq19", "period_from_times", "simulate_swing", "simulate_trace",
           "swing_accel", "swing_and_estimate", "swing_energy"]


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

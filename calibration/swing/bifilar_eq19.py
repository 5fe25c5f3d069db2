"""Izz of a bifilar pendulum by the paper's Equation 19, with its uncertainty budget.

Izz = m g D^2 T^2 / (16 pi^2 h) on the mean period of stopwatch timings
(:func:`izz_from_times`), with a first-order (GUM) propagation of the uncertainties of
m, D, h, g and the spread of T, reported input by input (:func:`eq19_budget`).
Geometry: strings of length ``h`` (m), attached ``D`` (m) apart; SI throughout. The
nonlinear large-angle model is :mod:`calibration.swing.bifilar_model`, the trace fit
:mod:`calibration.swing.bifilar_fit`; :mod:`calibration.swing.bifilar` gathers all three.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.constants import G_STANDARD_MPS2
from common.errors import UserError

G_STANDARD = G_STANDARD_MPS2  # m/s^2 (the name calibration has always used)



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


SPACING_RANGE_M = (0.01, 1.5)
LENGTH_RANGE_M = (0.05, 5.0)
MASS_MAX_KG = 50.0
GYRATION_RANGE = (0.2, 5.0)
"""Plausible radius of gyration sqrt(Izz/m) relative to the half spacing D/2: the strings
are attached to the body, so its mass lies at distances comparable to D/2."""


def geometry_warnings(mass_kg: float, spacing_m: float, length_m: float, izz_kgm2: float
                      ) -> list[str]:
    """One line per implausible bifilar input: spacing D or length h out of a lab's range
    (typed in cm or mm?), a mass in grams, or a period that does not fit the geometry
    (the radius of gyration sqrt(Izz/m) far from D/2)."""
    return plausibility_warnings(
        mass_kg, length_m, "h", izz_kgm2,
        arm=("string spacing D", "--spacing", spacing_m, SPACING_RANGE_M),
        reference=("the half spacing D/2", spacing_m / 2.0))


def plausibility_warnings(mass_kg: float, length_m: float, length_symbol: str, izz_kgm2: float, *,
                          arm: tuple[str, str, float, tuple[float, float]],
                          reference: tuple[str, float]) -> list[str]:
    """The checks of :func:`geometry_warnings` for any suspension: ``arm`` = (its name, its
    option, its value in m, its plausible range), ``reference`` = (the name and length in m
    that the radius of gyration is compared with)."""
    arm_name, arm_opt, arm_m, arm_range = arm
    out = []
    for name, opt, v, (lo, hi) in ((arm_name, arm_opt, arm_m, arm_range),
                                   (f"string length {length_symbol}", "--length", length_m,
                                    LENGTH_RANGE_M)):
        if not lo <= v <= hi:
            out.append(f"{name} = {v:g} m is outside {lo:g}-{hi:g} m ({opt} is in metres: "
                       f"typed in {'cm or mm' if v > hi else 'another unit'}?)")
    if mass_kg > MASS_MAX_KG:
        out.append(f"mass {mass_kg:g} kg is above {MASS_MAX_KG:g} kg (--mass is in kg: typed in g?)")
    ref_name, ref_m = reference
    if izz_kgm2 > 0 and mass_kg > 0 and ref_m > 0:
        ratio = math.sqrt(izz_kgm2 / mass_kg) / ref_m
        lo, hi = GYRATION_RANGE
        if not lo <= ratio <= hi:
            out.append(f"the period does not fit the geometry: radius of gyration sqrt(Izz/m) = "
                       f"{math.sqrt(izz_kgm2 / mass_kg):.3g} m is {ratio:.3g}x {ref_name} = "
                       f"{ref_m:g} m (expected {lo:g}-{hi:g}x): check {arm_opt}, --length "
                       "(metres), --mass (kg) and the timed oscillation count")
    return out


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
    warnings: list[str] = field(default_factory=list)
    """Implausible inputs, one line each (:func:`geometry_warnings`); the CLI prints them."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (scalars only)."""
        d = {k: getattr(self, k) for k in ("izz_kgm2", "izz_sigma_kgm2", "method",
                                           "contributions_kgm2", "inputs", "details")}
        d["izz_rel_sigma"] = self.izz_sigma_kgm2 / abs(self.izz_kgm2) if self.izz_kgm2 else None
        if self.warnings:
            d["warnings"] = list(self.warnings)
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
        warnings=geometry_warnings(mass_kg, spacing_m, length_m, izz),
    )

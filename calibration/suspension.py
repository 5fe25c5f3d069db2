"""Bifilar and trifilar suspensions: the geometry a swing fit needs, the trifilar formula.

A trifilar pendulum (three parallel strings of length L at radius R from the centre,
the centre of mass on the axis) lifts its body exactly as a bifilar one of spacing
D = 2R does: each string's lower end moves on a chord 2 R sin(th/2), the body rises by
L - sqrt(L^2 - 4 R^2 sin^2(th/2)). So the large-angle model of
:mod:`calibration.swing.bifilar_model` serves both with ``spacing_m = 2 R``, and the
small-angle formula I = m g R^2 T^2 / (4 pi^2 L) is Eq. 19 with D = 2R.
:class:`Suspension` carries either with its uncertainties and names its inputs in the
budget ("spacing" D or "radius" R); :func:`izz_trifilar_from_times` is the trifilar twin
of :func:`calibration.swing.bifilar_eq19.izz_from_times`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from calibration.swing.bifilar_eq19 import (
    G_STANDARD,
    IzzResult,
    check_geometry,
    geometry_warnings,
    izz_eq19,
    izz_from_times,
    plausibility_warnings,
)
from common.errors import UserError

RADIUS_RANGE_M = (0.01, 2.5)
"""Plausible trifilar radius R (m): table-top rigs to a 1 m platform; outside: cm or mm?"""

KINDS = ("bifilar", "trifilar")


def izz_trifilar(mass_kg: float, radius_m: float, length_m: float, period_s: float,
                 g: float = G_STANDARD) -> float:
    """Trifilar small-angle formula I = m g R^2 T^2 / (4 pi^2 L), kg m^2."""
    return mass_kg * g * radius_m**2 * period_s**2 / (4.0 * math.pi**2 * length_m)


def trifilar_warnings(mass_kg: float, radius_m: float, length_m: float, izz_kgm2: float
                      ) -> list[str]:
    """The trifilar twin of :func:`geometry_warnings`: R or L out of a lab's range, a mass in
    grams, a radius of gyration far from R."""
    return plausibility_warnings(mass_kg, length_m, "L", izz_kgm2,
                                 arm=("string radius R", "--radius", radius_m, RADIUS_RANGE_M),
                                 reference=("the string radius R", radius_m))


@dataclass(frozen=True)
class Suspension:
    """A body on a bifilar (``arm_m`` = spacing D) or trifilar (``arm_m`` = radius R)
    suspension of string length ``length_m``, with the standard uncertainties of the inputs
    and an optional fixture (tare) inertia to subtract. SI units."""

    kind: str
    mass_kg: float
    arm_m: float
    length_m: float
    u_mass_kg: float = 0.0
    u_arm_m: float = 0.0
    u_length_m: float = 0.0
    g: float = G_STANDARD
    u_g: float = 0.0
    tare_izz_kgm2: float = 0.0
    u_tare_kgm2: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")

    @property
    def spacing_m(self) -> float:
        """The bifilar spacing D with the same torque and rise (2R for a trifilar)."""
        return self.arm_m if self.kind == "bifilar" else 2.0 * self.arm_m

    @property
    def u_spacing_m(self) -> float:
        return self.u_arm_m if self.kind == "bifilar" else 2.0 * self.u_arm_m

    @property
    def arm_key(self) -> str:
        """The arm's name in budgets and inputs: "spacing" (D) or "radius" (R)."""
        return "spacing" if self.kind == "bifilar" else "radius"

    @property
    def sway_omega_rad_s(self) -> float:
        """Angular frequency of the body's pendulum swing on the strings, sqrt(g/L)."""
        return math.sqrt(self.g / self.length_m)

    def check(self) -> None:
        """One UserError line on non-physical inputs (named as the user typed them)."""
        for name, v in (("mass", self.mass_kg), (f"string {self.arm_key}", self.arm_m),
                        ("string length", self.length_m), ("g", self.g)):
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise UserError(f"{name} must be a positive finite number, got {v!r}")
        check_geometry(self.mass_kg, self.spacing_m, self.length_m, self.g)

    def izz_small_angle(self, period_s: float) -> float:
        """Gross Izz (no tare) from a small-angle period: Eq. 19 or its trifilar twin."""
        return float(izz_eq19(self.mass_kg, self.spacing_m, self.length_m, period_s, self.g))

    def warnings(self, izz_gross_kgm2: float) -> list[str]:
        """Implausible inputs, one line each."""
        if self.kind == "bifilar":
            return geometry_warnings(self.mass_kg, self.arm_m, self.length_m, izz_gross_kgm2)
        return trifilar_warnings(self.mass_kg, self.arm_m, self.length_m, izz_gross_kgm2)

    def inputs(self) -> dict[str, float | str]:
        """The inputs as the user gave them (JSON-ready)."""
        arm = "spacing_m" if self.kind == "bifilar" else "radius_m"
        return {"suspension": self.kind, "mass_kg": self.mass_kg, arm: self.arm_m,
                "length_m": self.length_m, "g": self.g, "u_mass_kg": self.u_mass_kg,
                f"u_{arm}": self.u_arm_m, "u_length_m": self.u_length_m, "u_g": self.u_g,
                "tare_izz_kgm2": self.tare_izz_kgm2, "u_tare_kgm2": self.u_tare_kgm2}


def izz_trifilar_from_times(times_s: Sequence[float], cycles: int, s: Suspension, *,
                            u_timing_s: float = 0.0) -> IzzResult:
    """I = m g R^2 T^2 / (4 pi^2 L) on the mean period of stopwatch timings, with the
    budget of :func:`izz_from_times` (R's contribution named "radius": 2 u(R)/R)."""
    if s.kind != "trifilar":
        raise ValueError("izz_trifilar_from_times needs a trifilar Suspension")
    s.check()
    res = izz_from_times(times_s, cycles, s.mass_kg, s.spacing_m, s.length_m,
                         u_mass_kg=s.u_mass_kg, u_spacing_m=s.u_spacing_m,
                         u_length_m=s.u_length_m, u_timing_s=u_timing_s,
                         tare_izz_kgm2=s.tare_izz_kgm2, u_tare_kgm2=s.u_tare_kgm2, g=s.g,
                         u_g=s.u_g)
    gross = res.details["izz_gross_kgm2"]
    res.method = "trifilar-times"
    res.contributions_kgm2["radius"] = res.contributions_kgm2.pop("spacing")
    res.inputs = {**s.inputs(), "cycles": cycles, "times_s": [float(x) for x in times_s],
                  "u_timing_s": u_timing_s}
    res.warnings = s.warnings(gross)
    return res

"""Plausibility of a fit, said out loud: residuals far from the stated noise, a body's mass
and radius of gyration outside what an air-table body can have, parameters the run gives
no information on. Each check returns lines that name the likely cause."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from common.plausible import (  # noqa: F401  (re-exported: the body rules' old home)
    BODY_GYRATION_RANGE_M,
    BODY_MASS_RANGE_KG,
    DENSEST_KG_M3,
    body_problems,
    smallest_gyration_m,
)

RESIDUAL_RATIO = 10.0
"""A residual RMS more than this factor above (or below its inverse times) the stated
measurement noise is reported by :func:`residual_warnings`."""


def residual_warnings(rms: np.ndarray, sigma_pos_m: float, sigma_yaw_rad: float) -> list[str]:
    """One line per residual (x, y, yaw) whose RMS is far from the stated noise, naming the
    likely causes: poses in millimetres, yaw in degrees, a wrong thrust-table unit or body."""
    pos = max(float(rms[0]), float(rms[1]))
    yaw = float(rms[2])
    deg = math.degrees
    return (_far_from_noise(
                "position", pos, sigma_pos_m, f"x {rms[0]:.3g} m, y {rms[1]:.3g} m", f"{pos:.3g} m",
                f"{sigma_pos_m:g} m (--sigma-pos)",
                "poses in millimetres instead of metres? a thrust table in the wrong unit "
                "(gf vs N)? another body's poses? the fit does not explain the data",
                "the sigmas are too large (the stated uncertainty is too pessimistic) or poses "
                "are in km")
            + _far_from_noise(
                "yaw", yaw, sigma_yaw_rad, f"{deg(yaw):.3g} deg", f"{deg(yaw):.3g} deg",
                f"{deg(sigma_yaw_rad):g} deg (--sigma-yaw-deg)",
                "yaw in degrees instead of radians? a thrust table in the wrong unit? another "
                "body's poses? the fit does not explain the data",
                "the sigmas are too large"))


def _far_from_noise(what: str, rms: float, sigma: float, rms_high: str, rms_low: str,
                    noise: str, causes_high: str, causes_low: str) -> list[str]:
    """The line of :func:`residual_warnings` for one residual: ``rms`` more than
    :data:`RESIDUAL_RATIO` times above or below the stated noise ``sigma``, else none."""
    if rms > RESIDUAL_RATIO * sigma:
        return [f"{what} residuals (rms {rms_high}) are {rms / sigma:.3g}x the stated noise "
                f"{noise}: {causes_high}"]
    if rms < sigma / RESIDUAL_RATIO:
        return [f"{what} residuals (rms {rms_low}) are {sigma / rms if rms else math.inf:.3g}x "
                f"below the stated noise {noise}: {causes_low}"]
    return []


# plausible for a body on an air table: its mass, and its radius of gyration sqrt(Izz/m)
# (the rules are common.plausible's, shared with every command; re-exported here)


def body_warnings(mass_kg: float, izz_kgm2: float, thrust_source: str = "the thrust table",
                  unit: str | None = None) -> list[str]:
    """One line when the estimated mass lies outside :data:`BODY_MASS_RANGE_KG`, or Izz
    gives a radius of gyration outside :data:`BODY_GYRATION_RANGE_M`, naming the thrust
    table's unit (``unit``, of ``thrust_source``) as the likely cause: thrusts scale the
    mass and Izz estimates one for one, and gf read as N is a factor 102."""
    what = body_problems(mass_kg, izz_kgm2)
    if not what:
        return []
    said = f" ({thrust_source} says unit = \"{unit}\")" if unit else f" ({thrust_source})"
    return [f"{'; '.join(what)}: implausible for an air-table body. Is the thrust table's unit "
            f"right{said}? A table measured in gram-force but labelled N gives thrusts, mass and "
            "Izz 102x too large (labelled gf but in N: 102x too small); or the run and the table "
            "are not of the same module"]


def no_information(names: Sequence[str], sigma: np.ndarray, thrust_n: np.ndarray) -> str:
    """'' when every estimated parameter has a finite sigma, else why not (naming them)."""
    bad = [n for j, n in enumerate(names) if not math.isfinite(float(sigma[6 + j]))]
    if not bad:
        return ""
    if not np.any(np.asarray(thrust_n) != 0):
        why = ("no thrust: every valve is closed in every command (or the thrust table gives "
               "0 N)")
    else:
        # said from the commands and the geometry only, never from where a fit ended
        from estimator.plant.model import wrench

        w = wrench(np.asarray(thrust_n, dtype=float))
        scale = float(np.max(np.abs(thrust_n)))
        has = {"mass": bool(np.any(np.hypot(w[:, 0], w[:, 1]) > 1e-9 * scale)),
               "izz": bool(np.any(np.abs(w[:, 2]) > 1e-12 * scale))}
        reasons = {"mass": "no net force (the thrusts cancel)",
                   "izz": "no torque (the commands never turn the module)"}
        if all(has.get(n, False) for n in bad):
            return (f"{', '.join(bad)} {'has' if len(bad) == 1 else 'have'} no information at "
                    "the point where the fit stopped (infinite sigma), although the commands "
                    "give net force and torque: the fit diverged, not the run; a long real run "
                    "cannot be integrated from one initial state: fit it by segments "
                    "(--segments auto)")
        why = "; ".join(f"{n}: {reasons.get(n, 'the run does not excite it')}" for n in bad
                        if not has.get(n, False))
    return (f"{', '.join(bad)} {'has' if len(bad) == 1 else 'have'} no information in this run "
            f"(infinite sigma): {why}")

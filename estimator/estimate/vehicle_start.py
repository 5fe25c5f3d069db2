"""A start for a vehicle's batch fit when nothing gives one: a vehicle's
vehicle.toml may say nothing of its mass and Izz, and it may be ten times the paper's module
(an air-bearing satellite of 23 kg), from which the fit does not converge. A short scan
(:func:`scan_start`): the first :data:`SCAN_SPAN_S` of the run fitted from a few masses a
decade apart (Izz from the thrusters' reach as radius of gyration), a few iterations each;
the fit with the lowest cost gives the start of the whole fit. Structures, today's module
(vehicles/tpods.toml: the paper's start) and vehicles whose [body] or ``--initial`` gives
the mass or Izz are not scanned."""

from __future__ import annotations

import math
from collections.abc import Mapping

from common.errors import UserError
from common.runfolder import Run
from estimator.batch.least_squares import estimate_run as least_squares_run
from estimator.batch.mass_scan import SCAN_ITERATIONS, SCAN_MASSES_KG, SCAN_SPAN_S


def scan_start(run: Run, table, names: tuple[str, ...], fixed: Mapping[str, float],
               initial: Mapping[str, float], *, clamp: bool = False,
               sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0)
               ) -> tuple[dict[str, float], str] | None:
    """``(start, note)`` from the scan, or None (nothing to scan: the mass or Izz is not
    estimated, or the caller's ``initial`` gives them)."""
    if not {"mass", "izz"} <= set(names) or {"mass", "izz"} & set(initial):
        return None
    t0 = float(run.pose_t[0])
    window = (t0, min(t0 + SCAN_SPAN_S, float(run.pose_t[-1])))
    reach = max(run.structure.extent_m(), 0.05) / math.sqrt(2.0)
    best = None
    for m in SCAN_MASSES_KG:
        start = {**initial, "mass": m, "izz": m * reach * reach}
        try:
            res = least_squares_run(run, table, window, clamp=clamp, names=names, fixed=fixed,
                                    initial=start, sigma_pos_m=sigma_pos_m,
                                    sigma_yaw_rad=sigma_yaw_rad, max_iter=SCAN_ITERATIONS,
                                    thrust_uncertainty=False)
        except (UserError, ValueError, FloatingPointError):
            continue
        cost = float(res.cost_history[-1]) if res.cost_history else math.inf
        if math.isfinite(cost) and res.mass_kg > 0 and res.izz_kgm2 > 0 and (
                best is None or cost < best[0]):
            best = (cost, res)
    if best is None:
        return None
    res = best[1]
    start = {**initial, "mass": float(res.mass_kg), "izz": float(res.izz_kgm2)}
    return start, (f"started from a scan of the first {window[1] - window[0]:.3g} s (masses "
                   f"{SCAN_MASSES_KG[0]:g}..{SCAN_MASSES_KG[-1]:g} kg): mass {start['mass']:.4g}, "
                   f"izz {start['izz']:.4g}")


def vehicle_scan(run: Run, table, names: tuple[str, ...], fixed: Mapping[str, float],
                 initial: Mapping[str, float], *, clamp: bool = False,
                 sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0)
                 ) -> tuple[dict[str, float], str] | None:
    """:func:`scan_start` for a run whose structure is a vehicle (not today's module at the
    origin) whose [body] gives neither mass nor Izz; None for every other run. The one
    rule shared by the final fit and ``--model auto``'s candidates."""
    s = run.structure
    if (s is None or s.kind != "vehicle" or s.is_single_at_origin
            or s.body.mass_kg is not None or s.body.izz_kgm2 is not None):
        return None
    return scan_start(run, table, names, fixed, initial, clamp=clamp, sigma_pos_m=sigma_pos_m,
                      sigma_yaw_rad=sigma_yaw_rad)

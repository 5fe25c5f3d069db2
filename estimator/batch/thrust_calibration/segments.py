"""A vehicle's per-thruster in-flight efficiencies from a whole run fitted by segments
(:mod:`estimator.shooting`), the mass known: the use case behind ``tpods calibrate thrust
RUN --mass KG --segments LEN|auto``. Writes the vehicle file with the efficiencies in its
forces (each with its sigma, the known mass's uncertainty included) and a dead thruster
marked ``health = "dead"``; returns a :class:`ThrustCalibration` (prints nothing)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import tomli_w

from common.argtypes import vehicle_file
from common.errors import UserError, Warnings
from common.outputs import result_output
from common.runfolder import read_run
from common.vehicle_toml import vehicle_document
from estimator.batch.thrust_calibration.vehicle import calibrated_vehicle
from estimator.shooting.health import thruster_health
from estimator.shooting.segments import parse_segments


@dataclass
class ThrustCalibration:
    """What a thrust calibration gives: ``doc`` (its JSON, also calibration.json), ``lines``
    (its text report), ``warnings``, and ``refusal`` (why no table was written: the command
    fails with it after the JSON) or None."""

    doc: dict
    lines: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    refusal: str | None = None


def by_segments_wanted(segments: str | None) -> bool:
    """True when ``segments`` (LEN, auto or none) asks for a fit by segments."""
    return segments is not None and parse_segments(segments) != math.inf


def calibrate_by_segments(run_dir: str | Path, mass: float, out: str | Path, *,
                          segments: str = "auto", mass_sigma: float = 0.0,
                          vehicle: str | Path | None = None,
                          window: tuple[float | None, float | None] | None = None,
                          sigma_pos: float = 0.01, sigma_yaw_deg: float = 1.0, per: str = "thruster",
                          izz: float | None = None, thrust_table: str | None = None,
                          force: bool = False,
                          on_warning: Callable[[str], object] | None = None) -> ThrustCalibration:
    """Efficiencies of the on/off valves of the run's vehicle (``vehicle``: another file)
    with Izz estimated, the run fitted by ``segments`` (length in s, or auto), ``mass`` kg
    known (``mass_sigma``); ``out``: the new vehicle.toml, or a folder that also receives
    calibration.json. ``per``, ``izz`` and ``thrust_table`` are refused unless left at
    their defaults (the fit estimates Izz of a vehicle of on/off valves). ``on_warning(line)``
    hears each warning as it arises."""
    if per != "thruster":
        raise UserError(f"--segments calibrates each thruster: drop --per {per}")
    if izz is not None or thrust_table is not None:
        raise UserError("--segments estimates Izz with the efficiencies of a vehicle of on/off "
                        "valves: drop --izz and --thrust-table")
    run = read_run(run_dir, vehicle_file(vehicle) if vehicle else None)
    v = run.structure
    if getattr(v, "kind", None) != "vehicle" or any(t.table is not None for t in v.thrusters):
        raise UserError(f"{run.path}: --segments calibrates a vehicle of on/off valves "
                        "(--vehicle FILE)")
    if window:
        run = run.window(*window)
    dest = result_output(str(out), "vehicle.toml", force=force, command="tpods calibrate thrust")
    rep = thruster_health(run.pose_t, run.pose, v, run.cmd_t, run.duty_pct, mass_kg=mass,
                          sigma_pos_m=sigma_pos, sigma_yaw_rad=math.radians(sigma_yaw_deg),
                          length_s=parse_segments(segments))
    fit = rep.fit
    if not fit.converged:
        raise UserError(f"{run.path}: the calibration by segments did not converge "
                        f"({fit.message}); no vehicle written")
    names, values, sig = [], [], []
    for j, t in enumerate(rep.thrusters):
        if t.verdict in ("dead", "reversed") or not math.isfinite(t.sigma):
            continue
        # the known mass's uncertainty moves every efficiency in proportion
        names.append(f"efficiency.{j + 1}")
        values.append(t.efficiency)
        sig.append(math.hypot(t.sigma, t.efficiency * mass_sigma / mass))
    new = calibrated_vehicle(v, names, values, np.diag(np.square(sig)), str(dest.main))
    verdict = {t.name: t.verdict for t in rep.thrusters}
    new = replace(new, thrusters=tuple(replace(t, health=verdict[t.name]) for t in new.thrusters))
    doc = {"run": str(run.path), "mass_kg": mass, "mass_sigma_kg": mass_sigma,
           "thruster_health": [t.to_dict() for t in rep.thrusters], **fit.to_dict(),
           "out": str(dest.main)}

    with dest.writing_main() as (main, d):
        main.write_text(f"# tpods calibrate thrust {run.path} --segments: in-flight efficiencies "
                        f"(--mass {mass:g}); force_sigma_n = their total sigma\n"
                        + tomli_w.dumps(vehicle_document(new.name, new.thrusters, new.valves,
                                                         new.body, main.parent,
                                                         supplies=new.supplies)))
        if d is not None:
            (d / "calibration.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    warnings = Warnings(on_warning, fit.warnings)
    if mass_sigma == 0:
        warnings.append("--mass-sigma not given: the efficiencies' sigma leaves out the known "
                        "mass's uncertainty")
    lines = [f"thrust calibration by segments on {run.path} ({len(fit.t)} poses in {fit.plan.n} "
             f"segments of {fit.plan.length_s:g} s); {fit.message}, {fit.iterations} iterations",
             *rep.lines(), f"  wrote {dest.main}" + (", calibration.json" if dest.is_folder else "")]
    return ThrustCalibration(doc, lines, warnings)

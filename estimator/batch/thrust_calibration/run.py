"""The in-situ thrust calibration of a run folder: the use case behind ``tpods calibrate
thrust``, callable from a notebook.

:func:`calibrate_thrust_run` reads the run of a body of known mass (kg, and Izz in kg m^2,
or Izz estimated with the factors), fits the factors of its thrust table or of its
vehicle's valves (:func:`estimator.batch.thrust_calibration.calibrate.calibrate_run`) and
writes the calibrated table (or vehicle.toml), with calibration.json in a folder. A vehicle
of on/off valves that single shooting cannot carry is fitted by segments instead
(:mod:`estimator.batch.thrust_calibration.segments`, said in the warnings). It returns a
:class:`~estimator.batch.thrust_calibration.segments.ThrustCalibration` and prints nothing.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import tomli_w

from common.argtypes import vehicle_file
from common.errors import UserError, Warnings
from common.outputs import not_an_input, result_output
from common.plausible import body_problems
from common.runfolder import read_run
from common.thrust_table import ThrustTable
from common.vehicle_toml import vehicle_document
from estimator.batch.thrust_calibration.calibrate import calibrate_run
from estimator.batch.thrust_calibration.segments import (
    ThrustCalibration,
    by_segments_wanted,
    calibrate_by_segments,
)
from estimator.batch.thrust_calibration.vehicle import calibrated_vehicle


def calibrate_thrust_run(run_dir: str | Path, mass: float, out: str | Path, *,
                         mass_sigma: float = 0.0, izz: float | None = None,
                         izz_sigma: float = 0.0, thrust_table: str | None = None,
                         vehicle: str | Path | None = None, per: str = "thruster",
                         model: str = "ideal", estimate_com: bool = False,
                         window: tuple[float | None, float | None] | None = None,
                         clamp: bool = False, sigma_pos: float = 0.01, sigma_yaw_deg: float = 1.0,
                         segments: str | None = None, force: bool = False,
                         on_warning: Callable[[str], object] | None = None) -> ThrustCalibration:
    """Factors ``per`` thruster, nozzle count, both or one common scale (with ``model``'s
    nuisance parameters) from the run in ``run_dir`` of a body of ``mass`` kg (``izz``
    kg m^2, or None: estimated); ``thrust_table``: a TOML or 'table2' (a vehicle run of
    on/off valves needs none); ``out``: the new table or vehicle file, or a folder;
    ``segments``: LEN or auto fits the run by segments. A factor that is not positive
    leaves no table written (``refusal``). ``on_warning(line)`` hears each warning as it
    arises (one about the known body before the fit, which may then fail)."""
    seg = dict(mass_sigma=mass_sigma, vehicle=vehicle, window=window, sigma_pos=sigma_pos,
               sigma_yaw_deg=sigma_yaw_deg, per=per, izz=izz, thrust_table=thrust_table, force=force,
               on_warning=on_warning)
    if by_segments_wanted(segments):
        return calibrate_by_segments(run_dir, mass, out, segments=segments, **seg)
    run = read_run(run_dir, vehicle_file(vehicle) if vehicle else None)
    body = run.structure if hasattr(run.structure, "thrusters") else None
    if body is None and thrust_table is None:
        raise UserError("--thrust-table is needed: the run is not a vehicle run (no vehicle.toml "
                        "in it and no --vehicle)")
    if run.structure is not None and body is None:
        raise UserError(f"{run.path}: a structure run: its modules' tables are calibrated one "
                        "module at a time (calibrate thrust is not built for structures)")
    dest = result_output(str(out), "vehicle.toml" if body is not None else "thrust_table.toml",
                         force=force, command="tpods calibrate thrust")
    builtin = thrust_table is not None and thrust_table.lower() == "table2"
    not_an_input(dest, run_dir, None if builtin or thrust_table is None else thrust_table)
    table = (None if thrust_table is None else ThrustTable.default() if builtin
             else ThrustTable.load(thrust_table))
    if body is not None:
        table = body.with_table(table) if table is not None else body
    if izz is None and izz_sigma:
        raise UserError("--izz-sigma is the uncertainty of a known --izz; without --izz, Izz is "
                        "estimated (its sigma is reported)")
    warnings = Warnings(on_warning, [  # before the fit, which may fail
        f"the known body (--mass, --izz): {p}: implausible for an air-table body (kg and kg m^2?)"
        for p in body_problems(mass, izz)])
    if window:
        run = run.window(*window)
    # a vehicle of on/off valves, per thruster, Izz estimated: a run single shooting cannot
    # carry is fitted by segments instead (said), whatever single shooting raised
    by_parts = (body is not None and per == "thruster" and izz is None and thrust_table is None
                and segments is None and all(t.table is None for t in body.thrusters))
    try:
        res = calibrate_run(run, table, mass_kg=mass, izz_kgm2=izz, mass_sigma_kg=mass_sigma,
                            izz_sigma_kgm2=izz_sigma, per=per, model=model, sigma_pos_m=sigma_pos,
                            sigma_yaw_rad=math.radians(sigma_yaw_deg), clamp=clamp,
                            estimate_com=estimate_com)
        failed = None if res.converged else f"did not converge ({res.iterations} iterations)"
    except UserError as exc:
        if not by_parts:
            raise
        failed = f"failed ({exc})"
    if failed and by_parts:
        warnings.append(f"single shooting {failed}: one initial state cannot carry this run; "
                        "fitting it by segments instead (--segments auto)")
        cal = calibrate_by_segments(run_dir, mass, out, segments="auto", **seg)
        cal.warnings = [*warnings, *cal.warnings]
        return cal
    if failed:
        raise UserError(f"{run.path}: the calibration {failed}; no table written")
    doc = res.to_dict()
    unusable = [n for n, v in zip(res.names, res.values, strict=True) if v <= 0]
    doc.update({"run": str(run.path), "thrust_table": "built-in Table 2" if builtin
                else thrust_table, "out": None if unusable else str(dest.main)})
    if body is not None:
        doc["vehicle"] = body.name
    if not unusable:
        _write(dest, res, doc, body, table, run.path, mass)
    warnings += res.warnings
    if mass_sigma == 0 or (izz is not None and izz_sigma == 0):
        warnings.append("--mass-sigma/--izz-sigma not given: the factors' sigma leaves out the "
                        "known values' uncertainty")
    refusal = (f"{run.path}: {', '.join(unusable)} not positive (a dead or reversed thruster, see "
               "the warnings): a table cannot hold it; no table written") if unusable else None
    lines = [] if unusable else _lines(res, run.path, mass, mass_sigma, izz, izz_sigma, table, dest)
    return ThrustCalibration(doc, lines, warnings, refusal)


def _write(dest, res, doc: dict, body, table, run_path, mass: float) -> None:
    """The calibrated vehicle file (a vehicle run) or table, and calibration.json in a folder."""
    with dest.writing_main() as (main, d):  # d: None for --out FILE.toml
        if body is not None:
            v = calibrated_vehicle(body, res.names, res.values, res.cov, str(main))
            main.write_text(f"# tpods calibrate thrust {run_path}: in-flight factors "
                            f"{dict(zip(res.names, np.round(res.values, 5).tolist(), strict=True))} "
                            f"(--mass {mass:g}); force_sigma_n = the factors' total "
                            "sigma\n" + tomli_w.dumps(vehicle_document(
                                v.name, v.thrusters, v.valves, v.body, main.parent,
                                supplies=v.supplies)))
        else:
            res.new_table(table, run=str(run_path)).save(main)
        if d is not None:
            (d / "calibration.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")


def _lines(res, run_path, mass, mass_sigma, izz, izz_sigma, table, dest) -> list[str]:
    """The text report: the known body, the factors with their budget, the residuals."""
    out = [f"thrust calibration on {run_path} ({len(res.t)} poses, t = {res.t[0]:.3f}.."
           f"{res.t[-1]:.3f} s; --per {res.per}, --model {res.model})"]
    if res.izz is None:
        out.append(f"  known body: m = {mass:.6g} +/- {mass_sigma:.2g} kg, "
                   f"Izz = {izz:.6g} +/- {izz_sigma:.2g} kg m^2")
    else:
        iz = res.izz
        out.append(f"  known body: m = {mass:.6g} +/- {mass_sigma:.2g} kg; Izz estimated: "
                   f"{iz['izz_kgm2']:.6g} +/- {iz['izz_sigma_kgm2']:.2g} kg m^2 (noise "
                   f"{iz['izz_sigma_noise_kgm2']:.2g}, mass {iz['izz_sigma_mass_kgm2']:.2g}, table "
                   f"{iz['izz_sigma_table_kgm2']:.2g})")
    out.append(f"  converged; {res.iterations} iterations, horizons "
               f"{', '.join(f'{h:.1f}' for h in res.stages)} s")
    b = res.budget()
    lim = res.limited_by()
    out.append(f"  {'factor':<16} {'value':>8} {'sigma':>8}   {'noise':>8} {'mass':>8} {'Izz':>8} "
               f"{'table':>8}   limited by")
    for n, v in zip(res.names, res.values, strict=True):
        p = b[n]
        out.append(f"  {n:<16} {v:8.4f} {p['total']:8.2g}   {p['noise']:8.2g} {p['mass']:8.2g} "
                   f"{p['izz']:8.2g} {p['table']:8.2g}   {lim[n]}")
    if res.reference_count is not None:
        out.append(f"  nozzle_scale.{res.reference_count} held at "
                   f"{table.nozzle_factor(res.reference_count):g} (reference count: the efficiencies "
                   "carry the common level)")
    if res.absorbed:
        out.append(f"  calibrated away (removed from the table's [uncertainty]): {', '.join(res.absorbed)}")
    out += [f"  {e:<5} = {v:.4g} +/- {res.extras_sigma[e]:.2g}" for e, v in res.extras.items()]
    rms = res.rms_residuals()
    out.append(f"  rms residuals: x {rms[0] * 100:.3f} cm, y {rms[1] * 100:.3f} cm, "
               f"yaw {math.degrees(rms[2]):.3f} deg")
    out.append(f"  wrote {dest.main}" + (", calibration.json" if dest.is_folder else ""))
    return out

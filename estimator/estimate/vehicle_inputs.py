"""``tpods estimate batch RUN --vehicle V --estimate mass,izz,cx,cy,delay,drop``: a vehicle
run's valve dead time and shared-supply drop estimated with the body
(:func:`estimator.batch.input_params.fit_input_params`), the joint covariance, the
warnings of an input parameter the run does not inform, and on a simulated run the
errors and the joint Cramér-Rao bound at the truth (run.json ``truth``; its ``delay_s``
and ``drop_per_valve`` when given, else those of the run folder's own ``vehicle.toml``, the
simulated vehicle, else the vehicle file's)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from common.errors import UserError
from common.runfolder import Run, read_run
from common.thrust_table import ThrustTable, load_thrust_table
from common.vehicle import Vehicle
from estimator.batch.input_params import crlb_input_params, fit_input_params
from estimator.batch.misfit import misfit_warnings
from estimator.batch.physical_signs import result_sign_warnings
from estimator.estimate.options import EstimateOptions, _windowed, as_window
from estimator.estimate.result import Estimate
from estimator.estimate.structure_run import _with_structure
from estimator.estimate.vehicle_start import scan_start

BODY_NAMES = ("mass", "izz", "cx", "cy")


def estimate_with_inputs(run: Run | str, table, o: EstimateOptions, plant: Sequence[str],
                         inputs: Sequence[str], log: Callable[[str], None] | None = None
                         ) -> Estimate:
    """The batch fit of ``plant`` (default mass, izz, cx, cy less ``--fixed``) and the
    input parameters ``inputs`` of a vehicle run (``o`` as for ``estimate_run``)."""
    if o.method != "ls":
        raise UserError("delay and drop are estimated by batch LS only (--method ls)")
    if o.model not in (None, "ideal"):
        raise UserError("--estimate with delay/drop takes the ideal model's parameters "
                        "(name friction ones in --estimate instead of --model)")
    run = read_run(run, structure=o.structure) if not isinstance(run, Run) else (
        _with_structure(run, o.structure) if o.structure is not None else run)
    v, table = valve_vehicle(run, table)
    fixed = dict(o.fixed or {})
    names = tuple(plant) or tuple(n for n in BODY_NAMES if n not in fixed)
    wrun = _windowed(run, as_window(o.window))
    initial = dict(o.initial or {})
    note = None
    input_initial = {k: initial.pop(k) for k in list(initial) if k in inputs}
    if not ({"mass", "izz"} & set(initial)) and v.body.mass_kg is None and v.body.izz_kgm2 is None:
        scanned = scan_start(wrun, table, names, fixed, initial, clamp=o.clamp,
                             sigma_pos_m=o.sigma_pos_m, sigma_yaw_rad=o.sigma_yaw_rad)
        if scanned is not None:
            initial, note = scanned
    initial = {**{k: x for k, x in v.initial_guess().items() if k in names}, **initial}
    res = fit_input_params(wrun.pose_t, wrun.pose, v, wrun.cmd_t, wrun.duty_pct, names=names,
                           input_names=tuple(inputs), fixed=fixed, initial=initial,
                           input_initial=input_initial, sigma_pos_m=o.sigma_pos_m,
                           sigma_yaw_rad=o.sigma_yaw_rad, max_iter=max(o.max_iter, 30))
    res.warnings += misfit_warnings(res.residuals, o.sigma_pos_m, o.sigma_yaw_rad,
                                    what="the batch fit")
    res.warnings += result_sign_warnings(res)  # a negative drop or damping: said, not clamped
    _add_considered(res, wrun, v, inputs, fixed, o)
    if log is not None:
        for w in res.warnings:
            log(f"tpods: warning: {w}")
    out: dict[str, Any] = {"method": "ls", "run": str(run.path), "model": "custom"}
    out.update(res.to_dict())
    out["input_params"] = {n: {"value": float(res.params[n]),
                               "sigma": float(res.sigma[6 + res.names.index(n)])
                               if n in res.names else None,
                               "estimated": n in res.names} for n in inputs}
    if note:
        out["start"] = note
    est = Estimate("ls", "custom", wrun, out, batch=res, start_note=note)
    _truth(est, out, run, wrun, v, res, inputs, o)
    return est


def _add_considered(res, wrun: Run, v: Vehicle, inputs, fixed, o: EstimateOptions) -> None:
    """Make the fit's sigma the total: the vehicle's stated force uncertainty (force_sigma_n,
    a table's, an unestimated drop's drop_sigma) considered at the joint solution
    (:func:`estimator.batch.input_consider.joint_consider`)."""
    from estimator.batch.input_consider import joint_consider

    c = joint_consider(res, wrun.pose, v, wrun.cmd_t, wrun.duty_pct, tuple(inputs), fixed=fixed,
                       sigma_pos_m=o.sigma_pos_m, sigma_yaw_rad=o.sigma_yaw_rad)
    if c is None:
        res.thrust_note = ("sigma = measurement noise, jointly with the estimated valve delay "
                           "and supply drop (the vehicle states no force uncertainty that "
                           "reaches these commands)")
        return
    res.add_thrust_covariance(c.cov_thrust, c.names)
    res.thrust_note = ("sigma = measurement noise + the vehicle's stated force uncertainty "
                       f"({', '.join(c.names)}), jointly with the estimated valve delay and "
                       "supply drop")


def valve_vehicle(run: Run, table) -> tuple[Vehicle, ThrustTable | None]:
    """``(vehicle, table)`` of a run of valve commands (the run's ``--vehicle``, with
    ``--thrust-table`` applied); one-line refusal for a run without one."""
    v = run.structure
    if v is None or v.kind != "vehicle" or run.thrust_n is not None or run.wrench_frame:
        raise UserError(f"{run.path}: delay and drop are a vehicle's valves: give --vehicle "
                        "FILE with a run of valve commands (commands.csv, no thrusts.csv)")
    if table is not None:
        v.check_table_option()
        table = table if isinstance(table, ThrustTable) else load_thrust_table(table)
        v = v.with_table(table)
    return v, table


def truth_inputs(run: Run, v: Vehicle) -> Vehicle:
    """``v`` with the valve delay and supply drops the run was made with: run.json truth's
    ``delay_s`` and ``drop_per_valve`` when given, else those of the run folder's own
    ``vehicle.toml`` (the simulated vehicle), else ``v``'s own."""
    truth = run.truth or {}
    own = run.path / "vehicle.toml"
    sim_v = Vehicle.load(own) if own.is_file() else v
    delay = truth.get("delay_s", sim_v.valves.delay_s)
    drops = truth.get("drop_per_valve")
    drops = ({s: sim_v.drop_of(s) for s in v.onoff_supplies()} if drops is None
             else {s: float(drops) for s in v.onoff_supplies()})
    return v.with_input_params(float(delay), drops)


def _truth(est, out, run, wrun, v, res, inputs, o) -> None:
    """Errors and the joint CRLB at run.json's truth (nothing without one)."""
    truth = run.truth or {}
    try:
        tp = {"mass": float(truth["mass_kg"]), "izz": float(truth["izz_kgm2"]),
              "cx": float(truth.get("cx", 0.0)), "cy": float(truth.get("cy", 0.0))}
    except (KeyError, TypeError, ValueError):
        return
    out.update({"truth_mass_kg": tp["mass"], "truth_izz_kgm2": tp["izz"],
                "mass_error_kg": res.mass_kg - tp["mass"], "izz_error_kgm2": res.izz_kgm2 - tp["izz"],
                "mass_rel_error": (res.mass_kg - tp["mass"]) / tp["mass"],
                "izz_rel_error": (res.izz_kgm2 - tp["izz"]) / tp["izz"]})
    tv = truth_inputs(run, v)
    s0 = truth.get("initial_state") if wrun.pose_t[0] == run.pose_t[0] else None
    plant = tuple(n for n in res.names if n not in inputs)
    try:
        c = crlb_input_params(wrun.pose_t, tv, wrun.cmd_t, wrun.duty_pct, tp, names=plant,
                              input_names=tuple(n for n in inputs if n in res.names),
                              s0=res.z0[:6] if s0 is None else np.asarray(s0, float),
                              sigma_pos_m=o.sigma_pos_m, sigma_yaw_rad=o.sigma_yaw_rad)
    except (UserError, ValueError, np.linalg.LinAlgError):
        return
    out["crlb_mass_sigma_kg"] = c.mass_sigma_kg
    out["crlb_izz_sigma_kgm2"] = c.izz_sigma_kgm2
    out["crlb_sigma"] = dict(zip(c.names, c.sigma.tolist(), strict=True))
    est.crlb = c

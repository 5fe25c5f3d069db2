"""The filter paths of :func:`estimator.estimate.estimate_run` (``--method ekf|ls-ekf``):
the ideal model's EKF (:func:`_ideal_filter`), the extended filter of the friction/tilt
models and of structures (:func:`_extended_filter`), and a filter's thrust-table
uncertainty budget (:func:`filter_thrust_budget`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from common.errors import UserError
from common.runfolder import Run
from common.thrust_table import ThrustTable
from estimator.batch.least_squares import BatchResult
from estimator.batch.least_squares import estimate_run as least_squares_run
from estimator.batch.model_select import ModelSelection
from estimator.batch.structure_degenerate import refuse_undetermined_run
from estimator.estimate.knowledge import BodyKnowledge
from estimator.estimate.options import EstimateOptions, Inputs, _windowed, as_window, filter_config
from estimator.estimate.result import Estimate
from estimator.estimate.structure_run import _structure_consider, com_keys
from estimator.filters.ekf import STATE_NAMES as FILTER_STATE_NAMES
from estimator.filters.ekf import estimate_filter, initial_rates
from estimator.filters.ext import ExtEkfConfig, estimate_ext


def _truth(run: Run) -> tuple[float, float] | None:
    """(mass, izz) of the run's truth (a simulated run), else None."""
    truth = run.truth or {}
    if "mass_kg" not in truth or "izz_kgm2" not in truth:
        return None
    return float(truth["mass_kg"]), float(truth["izz_kgm2"])


def filter_thrust_budget(out: dict[str, Any], run: Run, table: ThrustTable, *, clamp: bool,
                         names: Sequence[str], fixed: Mapping[str, float],
                         final: Mapping[str, float], sigma_pos_m: float,
                         sigma_yaw_rad: float) -> BatchResult | None:
    """Make a filter's ``mass_sigma_kg``/``izz_sigma_kgm2`` in ``out`` the TOTAL (noise +
    thrust table), with the budget keys of a batch estimate beside them.

    The thrust part is the batch consider covariance (:mod:`estimator.batch.consider`) of
    the same poses and commands, linearised at the least-squares optimum reached from the
    filter's final estimate ``final``: a filter's constant-parameter estimate is, to first
    order, the least-squares estimate of the data it has seen, so a thrust-table error
    moves both alike (exactly so for a common scale error, which moves m and Izz by the
    same fraction whatever the weighting of the data). The noise part stays the filter's
    own. Returns the fit used, or None when the table states no uncertainty or thrusts.csv
    gives the thrusts (``out["thrust_uncertainty"]["note"]`` then says so).
    """
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN

    out["mass_sigma_noise_kg"] = out.get("mass_sigma_kg")
    out["izz_sigma_noise_kgm2"] = out.get("izz_sigma_kgm2")
    out["mass_sigma_thrust_kg"] = 0.0
    out["izz_sigma_thrust_kgm2"] = 0.0
    if run.structure is not None:
        sens = run.thrust_sensitivity(table, clamp=clamp) if run.thrust_n is None else None
        note = (THRUSTS_GIVEN if run.thrust_n is not None else
                NO_UNCERTAINTY if sens is None or sens.empty else "")
    else:
        note = (THRUSTS_GIVEN if run.thrust_n is not None else
                NO_UNCERTAINTY if not table.states_uncertainty else "")
    res = None
    if not note:
        start = {k: float(v) for k, v in final.items()
                 if k in names and math.isfinite(v) and (k not in ("mass", "izz") or v > 0)}
        try:
            res = least_squares_run(run, table, (None, None), clamp=clamp, names=tuple(names),
                                    fixed=dict(fixed), initial=start, sigma_pos_m=sigma_pos_m,
                                    sigma_yaw_rad=sigma_yaw_rad,
                                    thrust_uncertainty=run.structure is None)
            if run.structure is not None:
                _structure_consider(res, run, table, clamp, sigma_pos_m, sigma_yaw_rad)
        except UserError as exc:
            note = f"the thrust part could not be computed ({exc}); sigma covers noise only"
        else:
            if res.cov_thrust is None or not res.converged:
                note = ("the thrust part could not be computed (the least-squares fit at the "
                        "filter's estimate did not converge); sigma covers noise only")
                res = None
    if res is not None:
        st = res.sigma_thrust
        for name, unit in (("mass", "kg"), ("izz", "kgm2")):
            if name in res.names and out.get(f"{name}_sigma_{unit}") is not None:
                t = float(st[6 + res.names.index(name)])
                out[f"{name}_sigma_thrust_{unit}"] = t
                out[f"{name}_sigma_{unit}"] = math.hypot(out[f"{name}_sigma_noise_{unit}"], t)
        note = (res.thrust_note + "; the thrust part from the least-squares linearisation of "
                "the same data")
    out["thrust_uncertainty"] = {"included": res is not None,
                                 "terms": list(res.thrust_terms) if res is not None else [],
                                 "note": note}
    return res


def _ideal_filter(inputs: Inputs, o: EstimateOptions, *, selection: ModelSelection | None,
                  note: str | None, log: Callable[[str], None] | None = None) -> Estimate:
    """``--method ekf|ls-ekf`` under the ideal model: the EKF on mass and Izz. ``o`` the
    resolved options (``model`` the model used, ``estimate`` the names, ``fixed`` and
    ``initial`` dicts, ``filter_options`` set)."""
    method, model, window, clamp = o.method, o.model, o.window, o.clamp
    names, fixed, initial, opts = o.estimate, o.fixed, o.initial, o.filter_options
    sigma_pos_m, sigma_yaw_rad, tol, max_iter = o.sigma_pos_m, o.sigma_yaw_rad, o.tol, o.max_iter
    if names != ("mass", "izz"):
        raise UserError("the filters estimate exactly mass and izz (drop --estimate or use "
                        "--method ls)")
    run, table = inputs()
    run = _windowed(run, as_window(window))
    cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
    cfg = filter_config(opts, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad, fixed=fixed)
    bad = [k for k in initial if k not in FILTER_STATE_NAMES]
    if bad:
        raise UserError(f"--initial {', '.join(bad)}: the filters start only x, y, psi, u, v, r, "
                        "m, izz (give known friction/tilt with --fixed)")
    x0 = np.array(cfg.x0, dtype=float)
    # start at the first pose, with velocities from a line fit of the first 0.25 s (the
    # run or window need not begin at rest), unless the initial guess says otherwise
    x0[:3] = run.pose[0]
    if method == "ekf" and not {"u", "v", "r"} & set(initial):
        rates, rsig = initial_rates(run.pose_t, run.pose)
        if np.all(np.isfinite(rsig)):
            x0[3:6] = rates
            s0 = np.array(cfg.sigma0)
            s0[3:6] = np.maximum(s0[3:6], 3 * rsig)
            cfg = cfg.with_(sigma0=tuple(s0.tolist()))
    for k, v in initial.items():
        x0[FILTER_STATE_NAMES.index(k)] = v
    if x0[6] <= 0 or x0[7] <= 0:
        raise UserError("initial mass and izz must be positive")
    ls_kwargs: dict[str, Any] = {}
    if method == "ls-ekf":
        ls_kwargs = {"tol": tol, "max_iter": max_iter}
        if initial:
            ls_kwargs["initial"] = initial
    try:
        fe = estimate_filter(run.pose_t, run.pose, cmd_t, thrust, method, cfg,
                             x0=x0 if method == "ekf" else None, ls_window_s=opts.ls_window_s,
                             ls_start=opts.ls_start, ls_kwargs=ls_kwargs)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    r = fe.result
    if log is not None:  # plausibility: as after a batch fit
        for w in ([fe.no_information + "; not converged"] if fe.no_information else []) + fe.warnings:
            log(f"tpods: warning: {w}")
    out: dict[str, Any] = {"run": str(run.path)}
    out.update(fe.to_dict())
    filter_thrust_budget(out, run, table, clamp=clamp, names=("mass", "izz"), fixed=fixed,
                         final={"mass": r.mass_kg, "izz": r.izz_kgm2}, sigma_pos_m=sigma_pos_m,
                         sigma_yaw_rad=sigma_yaw_rad)
    if log is not None and not out["thrust_uncertainty"]["included"]:
        log(f"tpods: warning: {out['thrust_uncertainty']['note']}")
    out["settings"] = {"preset": opts.preset, "q_psd": list(cfg.q_psd),
                       "sigma0": list(cfg.sigma0), "x0": x0.tolist(),
                       "sigma_meas": list(cfg.sigma_meas), "underweight": cfg.underweight,
                       "uw_trigger": cfg.uw_trigger}
    if (truth := _truth(run)) is not None:
        tm, ti = truth
        rm, ri = r.rmse(tm, ti)
        out.update({"truth_mass_kg": tm, "truth_izz_kgm2": ti,
                    "mass_error_kg": r.mass_kg - tm, "izz_error_kgm2": r.izz_kgm2 - ti,
                    "mass_rel_error": (r.mass_kg - tm) / tm,
                    "izz_rel_error": (r.izz_kgm2 - ti) / ti,
                    "rmse_mass_kg": rm, "rmse_izz_kgm2": ri,
                    "rmse_definition": "over every pose time from the first"})
    return Estimate(method, model, run, out, filter=fe, selection=selection, start_note=note,
                    config=cfg, x0=x0)


def _extended_filter(inputs: Inputs, o: EstimateOptions, *, selection: ModelSelection | None,
                     knowledge: BodyKnowledge | None = None) -> Estimate:
    """``--method ekf|ls-ekf`` under the friction/tilt models or on a structure: the
    extended filter (:mod:`estimator.filters.ext`). ``o`` the resolved options, as for
    :func:`_ideal_filter`; ``knowledge`` a structure's [body] knowledge."""
    method, model, window, clamp = o.method, o.model, o.window, o.clamp
    names, fixed, initial, opts = o.estimate, o.fixed, o.initial, o.filter_options
    sigma_pos_m, sigma_yaw_rad, tol, max_iter = o.sigma_pos_m, o.sigma_yaw_rad, o.tol, o.max_iter
    if knowledge is not None and not {"mass", "izz"} <= set(names):
        held = tuple(n for n in ("mass", "izz") if n not in names)
        why = (f"known from {knowledge.source} [body]" if set(held) & set(knowledge.known)
               else "fixed")
        raise UserError(f"--method {method} estimates mass and izz; {' and '.join(held)} "
                        f"{why}: add --estimate {','.join(names + held)} (the filter starts "
                        "at the known value) or use --method ls")
    run, table = inputs()
    run = _windowed(run, as_window(window))
    if run.structure is not None:  # an undetermined Izz (no torque) is refused as for ls
        refuse_undetermined_run(run, table, names=names, fixed=fixed, clamp=clamp,
                                sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
    q = {FILTER_STATE_NAMES[i]: v for i, v in opts.process_noise.items() if v}
    structure_guess: dict[str, float] = {}
    if run.structure is not None:
        # a structure: start from its geometry with a 100 % prior on m and Izz; the 1/m form
        # was overconfident with cx, cy estimated (18 sigma on Izz in a 60 s test run), the
        # direct form consistent
        structure_guess = {k: v for k, v in run.structure.initial_guess().items()
                           if k in names and k not in initial}
        initial = {**structure_guess, **initial}
    try:
        cfg = ExtEkfConfig(names=tuple(names), fixed=dict(fixed),
                           sigma_meas=(sigma_pos_m, sigma_pos_m, sigma_yaw_rad), q_psd=q,
                           param_form="direct" if run.structure is not None else "inverse")
    except ValueError as exc:
        raise UserError(str(exc)) from None
    from estimator.plant.output import com_from_tracked

    x0 = cfg.default_x0(None)
    for k, v in initial.items():
        if k not in cfg.labels:
            raise UserError(f"--initial {k}: not estimated by --model {model}")
        x0[cfg.labels.index(k)] = v
    # the centre of mass at the first pose (the states are the centre of mass's), then any
    # initial x, y, psi given
    b = cfg.base_params()
    cx = x0[cfg.labels.index("cx")] if "cx" in cfg.labels else b["cx"]
    cy = x0[cfg.labels.index("cy")] if "cy" in cfg.labels else b["cy"]
    x0[:3] = com_from_tracked(run.pose[0], cx, cy)
    for k in ("x", "y", "psi"):
        if k in initial:
            x0[cfg.labels.index(k)] = initial[k]
    P0 = cfg.default_P0()
    for k in ("mass", "izz"):
        if k in structure_guess:
            i = cfg.labels.index(k)
            P0[i, i] = structure_guess[k] ** 2
    priors = dict(knowledge.priors) if knowledge is not None else {}
    for k, (mean, sg) in priors.items():  # [body] priors: their mean and sigma start the filter
        i = cfg.labels.index(k)
        if k in structure_guess:  # not given with --initial
            x0[i] = mean
        P0[i, i] = sg**2
    for i, v in opts.sigma0.items():
        P0[i, i] = v**2
    ls_kwargs: dict[str, Any] = {"tol": tol, "max_iter": max_iter}
    if initial:
        ls_kwargs["initial"] = dict(initial)
    if priors:
        ls_kwargs["prior"] = knowledge.prior_vector(cfg.names)
    r, ls = estimate_ext(run.pose_t, run.pose, cmd_t, thrust, cfg, method, x0=x0, P0=P0,
                         ls_window_s=opts.ls_window_s, ls_start=opts.ls_start,
                         ls_kwargs=ls_kwargs)
    out: dict[str, Any] = {"method": method, "model": model, "run": str(run.path)}
    out.update(r.to_dict())
    final = dict(zip(cfg.labels, np.asarray(r.x[-1], float).tolist(), strict=False))
    filter_thrust_budget(out, run, table, clamp=clamp, names=names, fixed=fixed, final=final,
                         sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
    if ls is not None:
        out["ls"] = {"mass_kg": ls.mass_kg, "mass_sigma_kg": ls.mass_sigma_kg,
                     "izz_kgm2": ls.izz_kgm2, "izz_sigma_kgm2": ls.izz_sigma_kgm2,
                     "converged": ls.converged, "n_poses": int(len(ls.t)),
                     "ls_window_s": opts.ls_window_s, "ls_start": opts.ls_start}
    if selection is not None:
        out["model_selection"] = selection.to_dict()
    if run.structure is not None:
        # the centre of mass and Izz about the tracked origin, as for ls
        out.update(com_keys({**cfg.base_params(), **final}, cfg.names, r.P, run))
    if knowledge is not None:
        out.update(knowledge.to_dict())
    if (truth := _truth(run)) is not None:
        tm, ti = truth
        rm, ri = r.rmse(tm, ti)
        out.update({"truth_mass_kg": tm, "truth_izz_kgm2": ti,
                    "mass_error_kg": r.mass_kg - tm, "izz_error_kgm2": r.izz_kgm2 - ti,
                    "rmse_mass_kg": rm, "rmse_izz_kgm2": ri})
    return Estimate(method, model, run, out, ext=r, ext_ls=ls, selection=selection,
                    config=cfg, x0=x0)

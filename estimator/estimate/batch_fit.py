"""The batch least-squares path of :func:`estimator.estimate.estimate_run` (``--method
ls``, the paper's Algorithm 1): the fit, a structure's start, prior and thrust-table part,
the residual warnings, and on a simulated run the errors and the Cramér-Rao bound at the
truth (:func:`_least_squares`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from common.errors import UserError
from estimator.batch.crlb import crlb
from estimator.batch.least_squares import estimate_run as least_squares_run
from estimator.batch.misfit import misfit_warnings
from estimator.batch.misfit import summary as misfit_summary
from estimator.batch.model_select import ModelSelection
from estimator.batch.model_spread import candidate_rows
from estimator.batch.model_spread import spread as model_spread
from estimator.batch.physical_signs import result_sign_warnings
from estimator.batch.structure_degenerate import refuse_undetermined
from estimator.estimate.knowledge import BodyKnowledge
from estimator.estimate.options import EstimateOptions, Inputs, _windowed, as_window
from estimator.estimate.result import Estimate
from estimator.estimate.structure_run import _structure_consider, structure_keys
from estimator.estimate.vehicle_start import vehicle_scan


def _least_squares(inputs: Inputs, o: EstimateOptions, *, selection: ModelSelection | None,
                   note: str | None, log: Callable[[str], None] | None = None,
                   knowledge: BodyKnowledge | None = None) -> Estimate:
    """``--method ls``: the batch fit of the run. ``o`` the resolved options (``model`` the
    model used, ``estimate`` the names, ``fixed`` and ``initial`` dicts); ``note`` how the
    fit was started, ``knowledge`` a structure's [body] knowledge (its priors)."""
    model, window, clamp = o.model, o.window, o.clamp
    names, fixed, initial = o.estimate, o.fixed, o.initial
    sigma_pos_m, sigma_yaw_rad, tol, max_iter = o.sigma_pos_m, o.sigma_yaw_rad, o.tol, o.max_iter
    run, table = inputs()
    window = as_window(window)
    prior = None
    if run.structure is not None:
        body = run.structure.body
        # a vehicle (not today's module) that says nothing of its mass: scan for a start
        scanned = vehicle_scan(_windowed(run, window), table, names, fixed, initial, clamp=clamp,
                               sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
        if scanned is not None:
            initial, note = scanned[0], note or scanned[1]
        # a structure's start: its geometry (or its [body] values), not the paper's module
        guess = {k: v for k, v in run.structure.initial_guess().items()
                 if k in names and k not in initial}
        if guess:
            initial = {**guess, **initial}
            from_body = set(guess) & (set(body.known()) | set(body.priors()))
            src = ("geometry" if not from_body else
                   "[body] values" if from_body == set(guess) else "[body] values and geometry")
            note = note or (f"started from the structure's {src}: " + ", ".join(
                f"{k} {v:.4g}" for k, v in guess.items()))
        if knowledge is not None:  # [body] values with a sigma: a Gaussian prior
            prior = knowledge.prior_vector(names)
    res = least_squares_run(run, table, window, clamp=clamp, names=names, fixed=fixed,
                            initial=initial, sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad,
                            tol=tol, max_iter=max_iter,
                            thrust_uncertainty=run.structure is None, prior=prior)
    if run.structure is not None:
        # a structure run that cannot determine its unknowns is refused, naming them
        refuse_undetermined(res, _windowed(run, window).thrust_profile(table, clamp=clamp)[1],
                            str(run.path), fixed=tuple(fixed), structure=run.structure)
        _structure_consider(res, _windowed(run, window), table, clamp, sigma_pos_m, sigma_yaw_rad)
    if not (not res.converged and "no information" in res.message):
        # the model's misfit: residuals far above the noise, or structured
        res.warnings += misfit_warnings(res.residuals, sigma_pos_m, sigma_yaw_rad,
                                        what="the batch fit")
    res.warnings += result_sign_warnings(res)  # negative damping: said, not clamped
    spread_doc = None
    if selection is not None and {"mass", "izz"} <= set(res.names):
        # the model uncertainty: the answer's mass and Izz across the candidate models
        spread_doc, spread_warn = model_spread(
            candidate_rows(selection.fits, res, model),
            {"mass_kg": res.mass_sigma_kg, "izz_kgm2": res.izz_sigma_kgm2})
        res.warnings += spread_warn
    if log is not None:
        for w in res.warnings:
            log(f"tpods: warning: {w}")
        if res.cov_thrust is None and res.thrust_note:
            log(f"tpods: warning: {res.thrust_note}")
    out: dict[str, Any] = {"method": "ls", "run": str(run.path)}
    out.update(res.to_dict())
    out["misfit"] = misfit_summary(res.residuals, sigma_pos_m, sigma_yaw_rad)
    out["model"] = model
    if run.structure is not None:
        out.update(structure_keys(res, run))
    if knowledge is not None:
        out.update(knowledge.to_dict())
    if note:
        out["start"] = note
    if selection is not None:
        out["model_selection"] = selection.to_dict()
    if spread_doc is not None:
        out["model_spread"] = spread_doc
    wrun = _windowed(run, window)
    est = Estimate("ls", model, wrun, out, batch=res, selection=selection, start_note=note)
    try:
        tm, ti = float(run.truth["mass_kg"]), float(run.truth["izz_kgm2"])
    except (KeyError, TypeError, ValueError):
        return est
    out.update({"truth_mass_kg": tm, "truth_izz_kgm2": ti,
                "mass_error_kg": res.mass_kg - tm, "izz_error_kgm2": res.izz_kgm2 - ti,
                "mass_rel_error": (res.mass_kg - tm) / tm, "izz_rel_error": (res.izz_kgm2 - ti) / ti})
    truth = run.truth
    if {"mass", "izz"} <= set(res.names):
        # the bound of this very run at the truth, for the efficiency check
        cmd_t, thrust = wrun.thrust_profile(table, clamp=clamp)
        s0 = truth.get("initial_state") if wrun.pose_t[0] == run.pose_t[0] else None
        tp = {k: float(truth.get(k2, d)) for k, k2, d in (
            ("mass", "mass_kg", 0), ("izz", "izz_kgm2", 0), ("arm", "arm_m", 0.05),
            ("ct", "ct", 0), ("cr", "cr", 0), ("kb", "kb", 0), ("ax", "ax", 0), ("ay", "ay", 0),
            ("cx", "cx", 0), ("cy", "cy", 0))}
        if s0 is None:
            s0 = res.z0[:6]
        try:
            c = crlb(wrun.pose_t, cmd_t, thrust, tp, s0=s0, names=res.names,
                     sigma_pos_m=sigma_pos_m, sigma_yaw_rad=sigma_yaw_rad)
            out["crlb_mass_sigma_kg"] = c.mass_sigma_kg
            out["crlb_izz_sigma_kgm2"] = c.izz_sigma_kgm2
            for n, sg in zip(c.names, c.sigma, strict=True):
                if n in ("cx", "cy"):
                    out[f"crlb_{n}_sigma"] = float(sg)
            est.crlb = c
        except (UserError, ValueError, np.linalg.LinAlgError):
            pass
    return est

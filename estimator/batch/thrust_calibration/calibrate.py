"""In-situ thrust calibration: thruster efficiencies and nozzle-count scales from a run of a
body whose mass and Izz are known.

The bench characterises one nozzle at a time; on the assembled module a pinched tube, a
worn seat or another PWM frequency changes one thruster's thrust. With m and Izz known
(balance, bifilar pendulum) the poses of a run determine the thrusts, so the table's
in-situ factors (:class:`common.thrust_uncertainty.ThrustCalibration`)

    T_ij = eff_j * nozzle_scale_k * poly_k(D_ij)      (channel j, row i, k nozzles open)

can be estimated. Unknowns: the initial state ``s0`` (6), the model's extra parameters
(``friction``: ct, cr, kb; ``friction+tilt``: also ax, ay) and the factors ``f`` (P,
dimensionless):

- ``per="thruster"``: ``efficiency.1..4`` (their common level included);
- ``per="common"``: one ``scale`` of every thrust (written into the table as equal
  efficiencies, fully correlated);
- ``per="nozzles"``: ``nozzle_scale.k`` for every count k the run uses;
- ``per="both"``: both. Thrust only sees the products ``eff_j * nozzle_scale_k``, so
  raising every efficiency by a factor and lowering every nozzle scale by it changes
  nothing: the nozzle scale of the *reference count* (the count the run holds longest) is
  kept at its value (1), the efficiencies carry the level and the other counts' scales
  are relative to it. A run with a single count has nothing to add to ``thruster``: it
  is refused (its nozzle scale is confounded with the efficiencies' common level).

Fit: Gauss-Newton / Levenberg-Marquardt on ``sum_k r_k^T W r_k`` with ``r_k`` pose minus
prediction (yaw wrapped), over a growing horizon (5 s or 1 rad of yaw, then doubling)
as in :mod:`estimator.batch.least_squares`. Jacobian columns: initial state and extras
from :func:`estimator.batch.crlb.trajectory_stm`; factors from
:func:`estimator.batch.consider.output_sensitivity` with ``dT_ij/d eff_j = T_ij/eff_j`` and
``dT_ij/d nozzle_scale_k = T_ij/nozzle_scale_k`` on rows with k open (exact, no finite
differences). Each iteration re-evaluates the thrusts with the current factors.

Covariance of the factors (total = sum of the parts, each reported):

- ``noise``: the factor block of ``Lambda^-1`` (measurement noise, nuisance marginalised);
- ``mass``, ``izz``: the known values' standard uncertainties carried as consider
  parameters (``S P_c S^T``, their output sensitivities are the mass/Izz columns of the
  transition matrix);
- ``table``: the table's own stated uncertainty (:func:`common.thrust_uncertainty.thrust_sensitivity`
  of a table holding only the factors *not* estimated). A term the estimated factors
  absorb exactly (``[uncertainty] scale_rel`` when the efficiencies are estimated,
  ``[uncertainty.nozzles.k]`` when ``nozzle_scale.k`` is) is calibrated away: it drops
  from the factors' covariance and from the new table (the calibrated thrust no longer
  depends on it). Terms not absorbed (fit coefficients) stay in the new table *and*
  enter the factors' covariance (conservative: their negative cross-covariance with the
  factors cannot be written in the table format).

Refusals (:class:`common.errors.UserError` naming the reason): a thruster never opened
(for efficiencies), a run without thrust, ``both`` on a single nozzle count, and any run
whose information on the factors is singular or nearly so: the smallest eigenvalue of
the equilibrated (unit-diagonal) factor information below :data:`MIN_EIGENVALUE`; the
factors named are those with a large share of its eigenvector.

With ``izz_kgm2=None`` only the mass is known: Izz is estimated with the factors (an extra
column of the transition matrix, started from a linear solution), refused when the run does
not inform both (:mod:`estimator.batch.thrust_calibration.izz`). A vehicle or structure in
place of the table calibrates its thrusters' factors
(:mod:`estimator.batch.thrust_calibration.vehicle`). Factors near 0 or negative name a dead
or reversed thruster; residuals far above the noise or structured are reported
(:mod:`estimator.batch.misfit`).

This module holds the calibration itself (:func:`calibrate_thrust`, :func:`calibrate_run`);
the factors and the table are in :mod:`estimator.batch.thrust_factors`, the problem, its
solver and the separability checks in :mod:`estimator.batch.thrust_calibration.fit`, the
result in :mod:`estimator.batch.thrust_calibration.result` (their names stay importable
from here).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from common.errors import UserError
from common.plausible import thruster_factor_warnings
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import thrust_sensitivity
from estimator.batch.consider import output_sensitivity, segment_jacobian
from estimator.batch.crlb import DEFAULT_MAX_STEP_S, PARAM_SCALE, marginal_information, safe_inverse
from estimator.batch.ls_problem import first_horizon
from estimator.batch.misfit import misfit_warnings
from estimator.batch.misfit import summary as misfit_summary
from estimator.batch.plausibility import residual_warnings
from estimator.batch.thrust_calibration.fit import (  # noqa: F401  (re-exported)
    MAX_COMBINATION_SIGMA,
    MIN_EIGENVALUE,
    MODEL_EXTRAS,
    START_PRIOR,
    CalibrationFit,
    confounded,
    describe_confounding,
    gauss_newton,
    normal_equations,
    worst_combination,
)
from estimator.batch.thrust_calibration.izz import check_identifiable, izz_start, linear_start
from estimator.batch.thrust_calibration.result import (  # noqa: F401  (re-exported)
    ThrustCalibrationResult,
    izz_estimate,
    kept_covariance,
)
from estimator.batch.thrust_calibration.vehicle import (
    VehicleThrust,
    absorbed_on_rows,
    check_per,
    is_vehicle,
)
from estimator.batch.thrust_factors import (  # noqa: F401  (re-exported)
    ABSORB_TOL,
    N_CHANNELS,
    PER_CHOICES,
    absorbed_terms,
    channel_name,
    counts_used,
    factor_jacobian,
    factor_names,
    factor_thrust,
    probe_rows,
    remaining_uncertainty,
    with_factors,
)
from estimator.plant.model import ARM_M
from estimator.plant.output import output_jacobian


def calibrate_thrust(pose_t, pose, cmd_t, duty_pct, table: ThrustTable | Any, *, mass_kg: float,
                     izz_kgm2: float | None, mass_sigma_kg: float = 0.0, izz_sigma_kgm2: float = 0.0,
                     per: str = "thruster", model: str = "ideal", arm_m: float = ARM_M,
                     sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0),
                     clamp: bool = False, tol: float = 1e-8, max_iter: int = 30,
                     horizon0_s: float | None = 5.0,
                     max_step: float = DEFAULT_MAX_STEP_S,
                     izz0_kgm2: float | None = None,
                     estimate_com: bool = False) -> ThrustCalibrationResult:
    """Estimate the in-situ factors of ``table`` from a run of a body of known m and Izz.

    Args:
        pose_t: (N,) pose times, s (t0 = pose_t[0]); pose: (N, 3) x, y (m), yaw (rad).
        cmd_t, duty_pct: (Nc,), (Nc, 4) commands (duty percent, 0 = closed), held.
        table: the thrust table (its coefficients are kept; factors it already has are
            the start, and those not estimated are kept with their covariance); or a
            vehicle or structure (thrusters as data:
            :mod:`estimator.batch.thrust_calibration.vehicle`; ``per`` thruster or common,
            the factors relative to its thrusts; no new table: ``new_table`` is the
            table's).
        mass_kg, izz_kgm2: the known body; ``*_sigma_*``: their standard uncertainties.
            ``izz_kgm2=None``: Izz is estimated with the factors (only the mass known;
            :mod:`estimator.batch.thrust_calibration.izz`), from ``izz0_kgm2`` (default
            :func:`~estimator.batch.thrust_calibration.izz.izz_start`).
        per: ``thruster``, ``nozzles``, ``both`` or ``common`` (see the module doc).
        model: ``ideal``, ``friction`` or ``friction+tilt`` (nuisance parameters).
        sigma_pos_m, sigma_yaw_rad: pose noise.
        tol: largest scaled correction at convergence; max_iter: per stage.
        horizon0_s: first horizon of the growing-horizon start (None: all at once).
        estimate_com: estimate the centre of mass's offset cx, cy (m, body frame of the
            tracked origin) with the factors (reported in ``extras`` with their noise
            sigma); else it is at the tracked origin.

    Raises UserError for a run that cannot separate the factors (see the module doc).
    """
    if model not in MODEL_EXTRAS:
        raise UserError(f"--model must be one of {', '.join(MODEL_EXTRAS)}, got {model!r}")
    estimate_izz = izz_kgm2 is None
    for what, v in (("mass", mass_kg), ("Izz", izz_kgm2)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UserError(f"the known {what} must be positive, got {v:g}")
    for what, v in (("mass sigma", mass_sigma_kg), ("Izz sigma", izz_sigma_kgm2)):
        if not (math.isfinite(v) and v >= 0):
            raise UserError(f"the known {what} must be >= 0, got {v:g}")
    pose_t = np.asarray(pose_t, float)
    pose = np.asarray(pose, float)
    cmd_t = np.asarray(cmd_t, float)
    duty = np.asarray(duty_pct, float)
    if len(pose_t) < 10:
        raise UserError(f"{len(pose_t)} poses are too few to calibrate thrust")
    vehicle = is_vehicle(table)
    if vehicle:
        check_per(per)
    names, ref = factor_names(per, duty, cmd_t, float(pose_t[-1]))
    model_extras = MODEL_EXTRAS[model] + (("cx", "cy") if estimate_com else ())
    extras = model_extras + (("izz",) if estimate_izz else ())
    fixed = {"mass": float(mass_kg), "arm": float(arm_m)}
    if not estimate_izz:
        fixed["izz"] = float(izz_kgm2)
    fixed.update({k: 0.0 for k in ("ct", "cr", "kb", "ax", "ay") if k not in extras})
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    if vehicle:  # its thrusts as they are; the factors relative to them
        base = VehicleThrust(table, duty, arm_m, clamp, cmd_t=cmd_t)
        hold_t = base.hold_t  # the thrusts' rows: through the valves' dead time and rise
        f0 = np.ones(len(names))
        kept: tuple[str, ...] = ()
    else:
        base = with_factors(table, (), ())  # factor values as the table has them, no covariance
        f0 = np.array([1.0 if n == "scale" else
                       table.channel_factors(duty.shape[-1])[int(n.split(".")[1]) - 1]
                       if n.startswith("efficiency.") else table.nozzle_factor(int(n.split(".")[1]))
                       for n in names])
        cal = table.calibration
        kept = tuple(p for p in (cal.parameters if cal is not None else ()) if p not in names)
        hold_t = cmd_t
    i_izz = 5 + len(extras) if estimate_izz else None  # Izz: the last extra
    izz0 = None
    if estimate_izz:  # start from the linear solution (no damping): a dead thruster is far from 1
        _, fjac = (base.factor_thrust(names, np.ones(len(names))) if vehicle else
                   factor_thrust(base, duty, names, np.ones(len(names)), clamp))
        f_lin, izz_lin = linear_start(pose_t, pose, hold_t, fjac, mass_kg, arm_m)
        if f_lin is not None and not izz0_kgm2:
            f0 = np.clip(f_lin, -2.0, 3.0)
        izz0 = izz_start(mass_kg, izz0_kgm2, izz_lin)
    ex0 = np.array([izz0 if e == "izz" else 0.0 for e in extras])
    z = np.concatenate([pose[0], np.zeros(3), ex0, f0])
    scale = np.concatenate([np.ones(6), [izz0 if e == "izz" else PARAM_SCALE[e] for e in extras],
                            np.ones(len(names))])
    full = CalibrationFit(pose_t, pose, hold_t, duty, base, names, extras, fixed, w, clamp, max_step)
    ne = full.ne

    # separability, checked at the start (structure does not depend on the estimate)
    def check(z, cache) -> float:
        H, _ = full.jacobian(z, cache)
        Lam, _ = normal_equations(H, w, np.zeros((len(pose_t), 3)))
        if estimate_izz:
            check_identifiable(Lam, i_izz, ne, names, float(z[i_izz]))
        M = marginal_information(Lam, ne)
        lam_min, which = confounded(M, names)
        if lam_min < MIN_EIGENVALUE:
            raise UserError(describe_confounding(which, lam_min))
        worst, which = worst_combination(M, names)
        if worst > MAX_COMBINATION_SIGMA:
            raise UserError(describe_confounding(which, lam_min, worst))
        return lam_min

    cost, res, cache = full.evaluate(z)
    if not math.isfinite(cost):
        raise UserError("the start gives a non-finite trajectory (check --mass and --izz)")
    check(z, cache)

    t_rel = pose_t - pose_t[0]
    span = float(t_rel[-1])
    h = span if horizon0_s is None or horizon0_s <= 0 else first_horizon(t_rel, pose, horizon0_s)
    stats = {"iterations": 0}
    stages: list[float] = []
    while True:
        last = h >= 0.75 * span
        if last:
            h = span
        keep = t_rel <= h + 1e-9
        fit = full if last else CalibrationFit(pose_t[keep], pose[keep], hold_t, duty, base, names, extras,
                                     fixed, w, clamp, max_step)
        stages.append(h)
        z, converged, cost, res, cache = gauss_newton(
            fit, z, scale, reg=0.0 if last else START_PRIOR, tol=tol if last else 0.0,
            tol_sigma=None if last else 0.1, max_iter=max_iter, stats=stats)
        if last:
            break
        h = 2 * h
    # covariance at the estimate
    H, Jmi = full.jacobian(z, cache)
    Lam, _ = normal_equations(H, w, res)
    lam_min = check(z, cache)
    cov_all = safe_inverse(Lam)
    if not np.all(np.isfinite(cov_all[ne:, ne:])):
        raise UserError(describe_confounding(names, 0.0))
    b_mi = np.einsum("kin,i,kip->np", H, w, Jmi, optimize=True)
    S_mi = cov_all @ b_mi
    # the estimated quantities: the factors, and Izz (last) when it is estimated
    sl = list(range(ne, len(z))) + ([i_izz] if estimate_izz else [])
    Sm = S_mi[sl, 0:1]
    cov_mass = Sm @ Sm.T * mass_sigma_kg**2
    if estimate_izz:
        cov_izz = np.zeros((len(sl), len(sl)))
    else:
        Si = S_mi[sl, 1:2]
        cov_izz = Si @ Si.T * izz_sigma_kgm2**2
    # the table's own uncertainty, without the terms the factors absorb
    if vehicle:  # its stated uncertainty on the virtual thrusts
        sens = table.input_sensitivity(cmd_t, duty, clamp=clamp)[1]  # on hold_t's rows
        absorbed = absorbed_on_rows(sens, base.factor_thrust(names, z[ne:])[1])
    else:
        absorbed = absorbed_terms(table, names)
        work = with_factors(table, names, z[ne:],
                            parameters=kept,
                            covariance=kept_covariance(table, kept) if kept else None)
        sens = thrust_sensitivity(work, duty, clamp=clamp)
    keepc = [i for i, n in enumerate(sens.names) if n not in absorbed]
    table_terms = tuple(sens.names[i] for i in keepc)
    cov_table = np.zeros((len(sl), len(sl)))
    kept_cross = np.zeros((len(sl), len(kept))) if kept else None
    if keepc:
        params, grid, _, states = cache
        J = output_jacobian(states[grid.node_pos], output_sensitivity(
            states, grid, params, segment_jacobian(grid, sens.jacobian[..., keepc])), (),
            *CalibrationFit.offset(params))
        Pc = sens.covariance[np.ix_(keepc, keepc)]
        b = np.einsum("kin,i,kip->np", H, w, J, optimize=True)
        S = (cov_all @ b)[sl]
        cov_table = S @ Pc @ S.T
        if kept:
            idx = [table_terms.index(n) for n in kept]
            # errors as stated - true: a kept factor stated too high makes the fit
            # lower the estimated ones (the factors' error is -S times the kept error)
            kept_cross = -(S @ Pc)[:, idx]
    cov_noise = cov_all[np.ix_(sl, sl)]
    parts = {"noise": cov_noise, "mass": cov_mass, "izz": cov_izz,
             "table": 0.5 * (cov_table + cov_table.T)}
    P = len(names)
    cov = sum(parts.values())
    cov = 0.5 * (cov + cov.T)
    ex_sig = np.sqrt(np.maximum(np.diag(cov_all)[6:6 + len(model_extras)], 0.0))
    known = {"mass_kg": float(mass_kg), "mass_sigma_kg": float(mass_sigma_kg)}
    if not estimate_izz:
        known.update({"izz_kgm2": float(izz_kgm2), "izz_sigma_kgm2": float(izz_sigma_kgm2)})
    result = ThrustCalibrationResult(
        names, z[ne:].copy(), cov[:P, :P], cov_noise[:P, :P], cov_mass[:P, :P],
        cov_izz[:P, :P], parts["table"][:P, :P], table_terms, absorbed, ref, per, model,
        z[:6].copy(), {e: float(v) for e, v in zip(model_extras, z[6:6 + len(model_extras)], strict=True)},
        {e: float(s) for e, s in zip(model_extras, ex_sig, strict=True)},
        float(pose_t[0]), pose_t, res, stats["iterations"], converged, stages, lam_min,
        known, None if kept_cross is None else kept_cross[:P], kept)
    if estimate_izz:
        result.izz = izz_estimate(float(z[i_izz]), {k: v[P:, :] for k, v in parts.items()},
                                  names, result.sigma)
    result.warnings = residual_warnings(result.rms_residuals(), sigma_pos_m, sigma_yaw_rad)
    result.warnings += misfit_warnings(res, sigma_pos_m, sigma_yaw_rad, what="the calibration fit")
    result.misfit = misfit_summary(res, sigma_pos_m, sigma_yaw_rad)
    if not converged:
        result.warnings.append(f"not converged after {stats['iterations']} iterations")
    for n, s in zip(names, result.sigma, strict=True):
        if s > 0.1:
            result.warnings.append(f"{n} is poorly determined (sigma {s:.2g}): the run hardly "
                                   "excites it")
    # dead (near 0), reversed (negative) or outside 50-150 % (the wrong body?)
    result.warnings += thruster_factor_warnings(names, result.values, result.sigma)
    return result


def calibrate_run(run, table: ThrustTable, **kwargs) -> ThrustCalibrationResult:
    """:func:`calibrate_thrust` on a :class:`common.runfolder.Run` (commands.csv needed:
    a run that gives thrusts in newtons has no duty for the table's factors)."""
    if run.duty_pct is None:
        raise UserError(f"{run.path}: the run gives thrusts (thrusts.csv), not commands: "
                        "calibrating a thrust table needs commands.csv")
    return calibrate_thrust(run.pose_t, run.pose, run.cmd_t, run.duty_pct, table, **kwargs)

"""Batch nonlinear least squares (the paper's Algorithm 1) for the initial state and parameters.

The unknown is the augmented initial state ``z0 = (x0, y0, psi0, u0, v0, r0, theta)`` at
``t0 = pose_t[0]``, with ``theta`` the parameters in ``names`` (any subset of
``model.PARAM_NAMES``; the others are held at ``fixed``). Each iteration integrates
the reference trajectory and the transition matrix ``Phi(t, t0)`` together
(:func:`estimator.batch.crlb.trajectory_stm`: analytic Jacobians, parameter columns from the
augmented dynamics ``theta_dot = 0``), accumulates

    Lambda = Pbar^-1 + sum_k H_k^T R^-1 H_k,   lambda = Pbar^-1 dzbar + sum_k H_k^T R^-1 r_k

with ``H_k = [I_3 0] Phi(t_k, t0)`` and the residuals ``r_k = z_k - y(t_k)`` (yaw
residual wrapped to (-pi, pi], predicted yaw continuous), and solves the normal
equations ``Lambda dz = lambda``.

Guards: the normal equations are solved in scaled variables (mass and Izz in log space,
so a correction is relative; other parameters divided by :data:`estimator.batch.crlb.PARAM_SCALE`;
states by 1 m, 1 rad, 1 m/s, 1 rad/s) and equilibrated; a step that raises the cost is
retried with Levenberg-Marquardt damping, and no log-parameter moves by more than a
factor e per step; iterations are capped; ``converged`` is True only when the largest
scaled correction fell below ``tol``. Because wrapped yaw residuals make the cost
multi-modal far from the truth, the fit grows its horizon: first ``horizon0_s`` seconds
(or until the measured yaw has turned 1 rad), then the longest horizon over which the
predicted yaw's 3-sigma uncertainty stays below 1 rad (at least twice as long), each stage
starting from the last estimate and ending when every correction is below a tenth of its
sigma. Only those start-up stages carry a weak pseudo-prior on log m and log Izz.

The default prior is diffuse (no a priori information); ``prior=(zbar, Pbar)`` adds one.

This module holds the fit's entry points (:func:`batch_ls`, and :func:`estimate_run` on a
run folder with the thrust table's consider term); the problem of one horizon and the
solver are in :mod:`estimator.batch.ls_problem`, the result in
:mod:`estimator.batch.ls_result`, the plausibility checks in
:mod:`estimator.batch.plausibility` (their names stay importable from here).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence

import numpy as np

from common.argtypes import parse_time_window
from common.errors import UserError
from estimator.batch.crlb import DEFAULT_MAX_STEP_S, PARAM_SCALE, STATE_SCALE, safe_inverse
from estimator.batch.ls_problem import (  # noqa: F401  (DEFAULT_INITIAL, LOG_PARAMS, MISFIT_RATIO re-exported)
    DEFAULT_INITIAL,
    LOG_PARAMS,
    MISFIT_RATIO,
    STALL_RTOL,
    STALL_STEPS,
    HorizonProblem,
    as_prior,
    first_horizon,
    initial_vector,
    next_horizon,
    validate_inputs,
)
from estimator.batch.ls_problem import levenberg_marquardt as _lm
from estimator.batch.ls_result import BatchResult
from estimator.batch.plausibility import (  # noqa: F401  (re-exported: the checks' old home)
    BODY_GYRATION_RANGE_M,
    BODY_MASS_RANGE_KG,
    DENSEST_KG_M3,
    RESIDUAL_RATIO,
    body_warnings,
    no_information,
    residual_warnings,
    smallest_gyration_m,
)
from estimator.plant.model import ARM_M, PARAM_NAMES

_as_prior = as_prior  # the name tests and callers import

DEFAULT_TOL = 1e-8
"""Largest scaled correction at convergence (the paper's threshold)."""


def batch_ls(pose_t, pose, cmd_t, thrust_n, *, names: Sequence[str] = ("mass", "izz"),
             fixed: Mapping[str, float] | None = None,
             initial: Mapping[str, float] | np.ndarray | None = None,
             prior: tuple[np.ndarray, np.ndarray] | None = None,
             sigma_pos_m: float = 0.01, sigma_yaw_rad: float = math.radians(1.0),
             tol: float = DEFAULT_TOL, max_iter: int = 50, horizon0_s: float | None = 5.0,
             max_step: float = DEFAULT_MAX_STEP_S) -> BatchResult:
    """Batch least-squares estimate of the initial state and the parameters ``names``.

    Args:
        pose_t: (N,) pose times, s, strictly increasing; t0 = pose_t[0].
        pose: (N, 3) measured x, y (m) and yaw (rad, wrapped or not).
        cmd_t, thrust_n: (Nc,), (Nc, 4) thrusts in newtons held from each time to the
            next (zero before cmd_t[0]).
        names: estimated parameters (subset of model.PARAM_NAMES).
        fixed: values of the other parameters (``arm`` defaults to 0.05 m, ct, cr, kb, ax,
            ay to 0; mass and Izz must be given here when not estimated).
        initial: mapping of initial values (any of x, y, psi, u, v, r and parameter names)
            or a full (6+p,) vector. Default: the paper's m = 1 kg, Izz = 0.005 kg m^2,
            pose from the first measurement, velocities zero.
        prior: optional ``(zbar (6+p,), Pbar (6+p, 6+p))``; default diffuse. An entry
            with an infinite variance (its row and column otherwise zero) carries no
            information.
        sigma_pos_m, sigma_yaw_rad: measurement noise standard deviations.
        tol: largest scaled correction at convergence.
        max_iter: cap on Gauss-Newton iterations per stage.
        horizon0_s: first horizon of the growing-horizon start (None: whole span at once).
        max_step: longest integration step, s.
    """
    try:
        return _batch_ls(pose_t, pose, cmd_t, thrust_n, names=names, fixed=fixed,
                         initial=initial, prior=prior, sigma_pos_m=sigma_pos_m,
                         sigma_yaw_rad=sigma_yaw_rad, tol=tol, max_iter=max_iter,
                         horizon0_s=horizon0_s, max_step=max_step)
    except np.linalg.LinAlgError:
        raise UserError(
            "the least-squares fit broke down (singular normal equations): the poses do not "
            "fit the model at all; yaw in degrees instead of radians? poses in millimetres? a "
            "thrust table in the wrong unit? another body's poses?") from None


def _batch_ls(pose_t, pose, cmd_t, thrust_n, *, names, fixed, initial, prior, sigma_pos_m,
              sigma_yaw_rad, tol, max_iter, horizon0_s, max_step) -> BatchResult:
    t_start = time.perf_counter()
    names = tuple(names)
    bad = [n for n in names if n not in PARAM_NAMES]
    if bad or len(set(names)) != len(names) or not names:
        raise UserError(f"names must be distinct parameters from {', '.join(PARAM_NAMES)}, got {names}")
    if not (sigma_pos_m > 0 and sigma_yaw_rad > 0):
        raise UserError("measurement sigmas must be positive")
    pose_t, pose, cmd_t, thrust_n = validate_inputs(pose_t, pose, cmd_t, thrust_n)
    n = 6 + len(names)
    if 3 * len(pose_t) < n and prior is None:
        raise UserError(f"{len(pose_t)} poses cannot determine {n} unknowns")
    fixed_d = {"arm": ARM_M, "ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0, "ay": 0.0,
               "cx": 0.0, "cy": 0.0}
    fixed_d.update({k: float(v) for k, v in (fixed or {}).items()})
    for k in ("mass", "izz"):
        if k not in names and k not in fixed_d:
            raise UserError(f"{k} is neither estimated nor given in fixed")
    unknown = set(fixed_d) - set(PARAM_NAMES) - {"arm"}
    if unknown:
        raise UserError(f"unknown fixed parameter(s): {', '.join(sorted(unknown))}")
    z = initial_vector(initial, names, fixed_d, pose)
    zbar, prior_info = as_prior(prior, n)
    for j, name in enumerate(names):
        if name in LOG_PARAMS and not z[6 + j] > 0:
            raise UserError(f"initial {name} must be positive, got {z[6 + j]:g}")
    if not np.all(np.isfinite(z)):
        raise UserError("initial values must be finite")
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    scale = np.concatenate([STATE_SCALE, [1.0 if n in LOG_PARAMS else PARAM_SCALE[n] for n in names]])
    t_rel = pose_t - pose_t[0]
    span = float(t_rel[-1])
    full = HorizonProblem(pose_t, pose, cmd_t, thrust_n, names, fixed_d, w, zbar, prior_info, max_step)
    h = span if horizon0_s is None or horizon0_s <= 0 else first_horizon(t_rel, pose, horizon0_s)
    h = span if h >= 0.75 * span else h
    horizons: list[float] = []
    history: list[float] = []
    stats = {"iterations": 0, "rejected": 0}
    converged = False
    h_prev = prev = None
    failed = ""
    while True:
        last = h >= span
        if last:
            prob = full
        else:
            keep = t_rel <= h + 1e-9
            prob = HorizonProblem(pose_t[keep], pose[keep], cmd_t, thrust_n, names, fixed_d, w, zbar,
                            prior_info, max_step)
        if h_prev is not None and not math.isfinite(prob.evaluate(z)[0]):
            # the start-up estimate blows up on the longer horizon: grow less
            if h - h_prev > 0.05 * h_prev:
                h = 0.5 * (h_prev + h)
                continue
            failed = (f"the predicted trajectory is not finite beyond t = {h_prev:.3g} s from "
                      f"the estimate on the first {h_prev:.3g} s; the result covers only them")
            prob = prev
            cost, res, states = prob.evaluate(z)
            converged = False
            Lam = None
            break
        horizons.append(h)
        z, converged, Lam, Lq, res, states = _lm(prob, z, scale, tol if last else 0.0,
                                                 None if last else 0.1, max_iter, history,
                                                 stats, reg=0.0 if last else 1.0)
        if last:
            break
        h_prev, prev = h, prob
        h = next_horizon(h, span, z, Lq, full, t_rel)
    # Covariance: when converged, Lambda of the last linearisation (the final correction
    # was below tol, so it is the same to ~tol); otherwise Lambda at the returned point.
    if not converged or Lam is None:
        Lam, _ = prob.normal(z, res, states)
    cov = safe_inverse(Lam)
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    params = prob.params(z)

    def pick(name):
        if name in names:
            i = 6 + names.index(name)
            return params[name], float(sigma[i]), i
        return params[name], 0.0, None

    m, sm, im = pick("mass")
    izz, si, ii = pick("izz")
    corr = float(cov[im, ii] / (sigma[im] * sigma[ii])) if im is not None and ii is not None else float("nan")
    msg = ("converged" if converged else
           f"not converged after {stats['iterations']} iterations ({stats['rejected']} rejected steps)")
    if stats.get("stalled"):
        msg = (f"not converged: stalled after {stats['iterations']} iterations (the cost fell by "
               f"less than {STALL_RTOL:g} of itself in {STALL_STEPS} steps in a row at "
               f"{stats['stalled']:.3g}x the noise's): the model does not fit the data")
    if failed:
        msg = "not converged: " + failed
    rms = np.sqrt(np.mean(res**2, axis=0))
    warnings = residual_warnings(rms, sigma_pos_m, sigma_yaw_rad)
    return BatchResult(z, cov, sigma, names, params, float(pose_t[0]), prob.pose_t, res,
                       stats["iterations"], bool(converged), history, m, izz, sm, si, corr, msg,
                       horizons, time.perf_counter() - t_start, Lam, warnings,
                       reference=(prob.grid, states, prob.pose_t, prob.max_step, z.copy(),
                                  dict(params)))


def parse_window(text: str | None) -> tuple[float | None, float | None]:
    """``"T0:T1"`` (either side may be empty; ``"T0,T1"`` is read too) -> (t0, t1) in seconds."""
    try:
        return parse_time_window(text)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def estimate_run(run, table=None, window: tuple[float | None, float | None] | str | None = None,
                 *, clamp: bool = False, thrust_uncertainty: bool = True, **kwargs) -> BatchResult:
    """:func:`batch_ls` on a :class:`common.runfolder.Run` (thrusts from the run's table).

    A fit in which an estimated parameter has no information (infinite sigma: no thrust,
    no torque) is not converged, its ``message`` naming the parameter and why
    (:func:`no_information`).

    With ``thrust_uncertainty`` (default) the result's sigma is the TOTAL: measurement
    noise plus the thrust table's stated uncertainty carried as a consider covariance
    (:mod:`estimator.batch.consider`; ``cov_noise``/``cov_thrust`` hold the parts). A table
    that states none, or thrusts given in thrusts.csv, leave sigma at the noise part and
    say so in ``thrust_note`` (callers print it as a warning).

    ``window`` is ``(t0, t1)`` or ``"T0:T1"`` in seconds; other keywords go to batch_ls.
    """
    from common.thrust_table import load_thrust_table
    from common.thrust_uncertainty import thrust_sensitivity
    from estimator.batch.consider import NO_UNCERTAINTY, THRUSTS_GIVEN, batch_consider

    if isinstance(window, str) or window is None:
        window = parse_window(window)
    if window != (None, None):
        run = run.window(*window)
    cmd_t, thrust = run.thrust_profile(table, clamp=clamp)
    res = batch_ls(run.pose_t, run.pose, cmd_t, thrust, **kwargs)
    empty = no_information(res.names, res.sigma, thrust)
    if empty:
        # an uninformative fit is not a result: it stays at the initial guess +/- inf
        res.converged = False
        res.message = "not converged: " + empty
        res.warnings = []  # the residuals say nothing more than that
        return res
    if not thrust_uncertainty:
        return res
    if run.thrust_n is not None:
        res.thrust_note = THRUSTS_GIVEN
    else:
        table = table if table is not None else load_thrust_table(None)
        if not table.states_uncertainty:
            res.thrust_note = NO_UNCERTAINTY
        else:
            sens = thrust_sensitivity(table, run.duty_pct, clamp=clamp)
            c = batch_consider(res, cmd_t, sens,
                               sigma_pos_m=kwargs.get("sigma_pos_m", 0.01),
                               sigma_yaw_rad=kwargs.get("sigma_yaw_rad", math.radians(1.0)),
                               max_step=kwargs.get("max_step", DEFAULT_MAX_STEP_S))
            res.add_thrust_covariance(c.cov_thrust, c.names)
            res.thrust_note = ("sigma = measurement noise + thrust table uncertainty "
                               f"({', '.join(_term_groups(c.names))})")
    return res


def _term_groups(names: Sequence[str]) -> list[str]:
    """Readable groups of consider parameter names: scale, scale per count, coefficients..."""
    out = []
    if "scale" in names:
        out.append("common scale")
    ks = [n.split(".")[1] for n in names if n.startswith("scale.")]
    if ks:
        out.append(f"scale of {', '.join(ks)} open")
    ks = sorted({n.split(".")[1] for n in names if n.startswith("coef.")})
    if ks:
        out.append(f"fit coefficients of {', '.join(ks)} open")
    if any(n.startswith(("efficiency.", "nozzle_scale.")) for n in names):
        out.append("in-situ calibration")
    return out

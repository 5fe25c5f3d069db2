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
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.argtypes import parse_time_window
from common.errors import UserError
from common.plausible import (  # noqa: F401  (re-exported: the body rules' old home)
    BODY_GYRATION_RANGE_M,
    BODY_MASS_RANGE_KG,
    DENSEST_KG_M3,
    body_problems,
    smallest_gyration_m,
)
from estimator.batch.crlb import (
    DEFAULT_MAX_STEP_S,
    PARAM_SCALE,
    STATE_SCALE,
    fisher_information,
    make_grid,
    reference_states,
    safe_inverse,
    trajectory_stm,
)
from estimator.plant.model import (
    ARM_M,
    PARAM_NAMES,
    STATE_NAMES,
    com_from_tracked,
    output_jacobian,
    tracked_pose,
    wrap_angle,
)

DEFAULT_INITIAL = {"mass": 1.0, "izz": 0.005, "ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0,
                   "ay": 0.0, "cx": 0.0, "cy": 0.0}
"""The paper's initial guess (m = 1 kg, Izz = 0.005 kg m^2); friction, tilt and the centre
of mass's offset from the tracked origin zero."""

DEFAULT_TOL = 1e-8
"""Largest scaled correction at convergence (the paper's threshold)."""


@dataclass
class BatchResult:
    """Result of :func:`batch_ls` (SI units).

    Attributes:
        z0: (6+p,) estimate at ``t0``: x0, y0 (m), psi0 (rad), u0, v0 (m/s), r0 (rad/s),
            then the parameters in ``names`` order.
        cov: (6+p, 6+p) covariance ``Lambda^-1``; ``sigma`` its square-root diagonal.
        names: estimated parameters; ``params``: every model parameter used (estimated and fixed).
        mass_kg, izz_kgm2, mass_sigma_kg, izz_sigma_kgm2, corr_mass_izz: convenience
            copies (sigma 0 and correlation NaN for a fixed parameter).
        t: (N,) pose times; residuals: (N, 3) measured minus predicted pose (yaw wrapped).
        iterations: accepted Gauss-Newton steps over all stages; converged: the last
            correction was below ``tol``; cost_history: cost after every accepted step
            (the first entry is the initial cost of each stage); stages: horizon of each stage, s.
    """

    z0: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    names: tuple[str, ...]
    params: dict[str, float]
    t0: float
    t: np.ndarray
    residuals: np.ndarray
    iterations: int
    converged: bool
    cost_history: list[float]
    mass_kg: float
    izz_kgm2: float
    mass_sigma_kg: float
    izz_sigma_kgm2: float
    corr_mass_izz: float
    message: str = ""
    stages: list[float] = field(default_factory=list)
    elapsed_s: float = 0.0
    fisher: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)
    cov_noise: np.ndarray | None = None
    cov_thrust: np.ndarray | None = None
    thrust_terms: tuple[str, ...] = ()
    thrust_note: str = ""

    def add_thrust_covariance(self, cov_thrust: np.ndarray, terms: tuple[str, ...]) -> None:
        """Make ``cov``/``sigma`` (and the mass/Izz copies) the TOTAL: measurement noise
        plus the thrust table's consider part ``cov_thrust`` (:mod:`estimator.batch.consider`)."""
        if self.cov_noise is None:
            self.cov_noise = self.cov
        self.cov_thrust = cov_thrust
        self.thrust_terms = tuple(terms)
        self.cov = self.cov_noise + cov_thrust
        self.sigma = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        for name, attr in (("mass", "mass_sigma_kg"), ("izz", "izz_sigma_kgm2")):
            if name in self.names:
                setattr(self, attr, float(self.sigma[6 + self.names.index(name)]))
        if "mass" in self.names and "izz" in self.names:
            im, ii = 6 + self.names.index("mass"), 6 + self.names.index("izz")
            self.corr_mass_izz = float(self.cov[im, ii] / (self.sigma[im] * self.sigma[ii]))

    @property
    def sigma_noise(self) -> np.ndarray:
        """(6+p,) standard deviations from measurement noise alone."""
        c = self.cov if self.cov_noise is None else self.cov_noise
        return np.sqrt(np.maximum(np.diag(c), 0.0))

    @property
    def sigma_thrust(self) -> np.ndarray:
        """(6+p,) standard deviations from the thrust table's uncertainty (0 without one)."""
        if self.cov_thrust is None:
            return np.zeros(len(self.z0))
        return np.sqrt(np.maximum(np.diag(self.cov_thrust), 0.0))

    def budget(self) -> dict[str, tuple[float, float, float]]:
        """``{parameter: (sigma_noise, sigma_thrust, sigma_total)}`` in SI units."""
        sn, st, s = self.sigma_noise, self.sigma_thrust, self.sigma
        return {n: (float(sn[6 + j]), float(st[6 + j]), float(s[6 + j]))
                for j, n in enumerate(self.names)}

    @property
    def labels(self) -> tuple[str, ...]:
        return STATE_NAMES + self.names

    def rms_residuals(self) -> np.ndarray:
        """(3,) RMS of the x, y (m) and yaw (rad) residuals."""
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no per-pose arrays)."""
        with np.errstate(invalid="ignore"):  # inf / inf for a direction without information
            corr = self.cov / np.outer(np.where(self.sigma > 0, self.sigma, 1),
                                       np.where(self.sigma > 0, self.sigma, 1))
        return {
            "mass_kg": self.mass_kg, "mass_sigma_kg": self.mass_sigma_kg,
            "izz_kgm2": self.izz_kgm2, "izz_sigma_kgm2": self.izz_sigma_kgm2,
            "corr_mass_izz": None if math.isnan(self.corr_mass_izz) else self.corr_mass_izz,
            "converged": self.converged, "iterations": self.iterations,
            "estimated": list(self.names), "params": self.params,
            "z0": dict(zip(self.labels, self.z0.tolist(), strict=True)),
            "sigma": dict(zip(self.labels, self.sigma.tolist(), strict=True)),
            "correlation": corr.tolist(),
            "t0_s": self.t0, "n_poses": int(len(self.t)),
            "rms_residual_x_m": float(self.rms_residuals()[0]),
            "rms_residual_y_m": float(self.rms_residuals()[1]),
            "rms_residual_yaw_rad": float(self.rms_residuals()[2]),
            "final_cost": self.cost_history[-1] if self.cost_history else None,
            "cost_history": self.cost_history, "stages_s": self.stages,
            "message": self.message, "elapsed_s": self.elapsed_s,
            **self._budget_dict(),
            **({"warnings": list(self.warnings)} if self.warnings else {}),
        }

    def _budget_dict(self) -> dict[str, Any]:
        """The uncertainty budget keys of :meth:`to_dict` (sigma = total; RSS of the parts)."""
        sn, st = self.sigma_noise, self.sigma_thrust
        out: dict[str, Any] = {}
        for name, unit in (("mass", "kg"), ("izz", "kgm2")):
            if name in self.names:
                i = 6 + self.names.index(name)
                out[f"{name}_sigma_noise_{unit}"] = float(sn[i])
                out[f"{name}_sigma_thrust_{unit}"] = float(st[i])
        out["sigma_noise"] = dict(zip(self.labels, sn.tolist(), strict=True))
        out["sigma_thrust"] = dict(zip(self.labels, st.tolist(), strict=True))
        out["thrust_uncertainty"] = {"included": self.cov_thrust is not None,
                                     "terms": list(self.thrust_terms),
                                     "note": self.thrust_note}
        return out


RESIDUAL_RATIO = 10.0
"""A residual RMS more than this factor above (or below its inverse times) the stated
measurement noise is reported by :func:`residual_warnings`."""


def residual_warnings(rms: np.ndarray, sigma_pos_m: float, sigma_yaw_rad: float) -> list[str]:
    """One line per residual (x, y, yaw) whose RMS is far from the stated noise, naming the
    likely causes: poses in millimetres, yaw in degrees, a wrong thrust-table unit or body."""
    out = []
    pos = max(float(rms[0]), float(rms[1]))
    yaw = float(rms[2])
    if pos > RESIDUAL_RATIO * sigma_pos_m:
        out.append(f"position residuals (rms x {rms[0]:.3g} m, y {rms[1]:.3g} m) are "
                   f"{pos / sigma_pos_m:.3g}x the stated noise {sigma_pos_m:g} m (--sigma-pos): "
                   "poses in millimetres instead of metres? a thrust table in the wrong unit "
                   "(gf vs N)? another body's poses? the fit does not explain the data")
    elif pos < sigma_pos_m / RESIDUAL_RATIO:
        out.append(f"position residuals (rms {pos:.3g} m) are {sigma_pos_m / pos if pos else math.inf:.3g}x "
                   f"below the stated noise {sigma_pos_m:g} m (--sigma-pos): the sigmas are too "
                   "large (the stated uncertainty is too pessimistic) or poses are in km")
    if yaw > RESIDUAL_RATIO * sigma_yaw_rad:
        out.append(f"yaw residuals (rms {math.degrees(yaw):.3g} deg) are {yaw / sigma_yaw_rad:.3g}x "
                   f"the stated noise {math.degrees(sigma_yaw_rad):g} deg (--sigma-yaw-deg): yaw in "
                   "degrees instead of radians? a thrust table in the wrong unit? another body's "
                   "poses? the fit does not explain the data")
    elif yaw < sigma_yaw_rad / RESIDUAL_RATIO:
        out.append(f"yaw residuals (rms {math.degrees(yaw):.3g} deg) are "
                   f"{sigma_yaw_rad / yaw if yaw else math.inf:.3g}x below the stated noise "
                   f"{math.degrees(sigma_yaw_rad):g} deg (--sigma-yaw-deg): the sigmas are too large")
    return out


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
        reasons = {"mass": "no net force (the thrusts cancel)",
                   "izz": "no torque (the commands never turn the module)"}
        why = "; ".join(f"{n}: {reasons.get(n, 'the run does not excite it')}" for n in bad)
    return (f"{', '.join(bad)} {'has' if len(bad) == 1 else 'have'} no information in this run "
            f"(infinite sigma): {why}")


def _as_prior(prior, n: int):
    if prior is None:
        return None, None
    zbar, P = prior
    zbar = np.asarray(zbar, float).reshape(-1)
    P = np.asarray(P, float)
    # an infinite variance on the diagonal (its row and column otherwise zero): no information
    diffuse = np.isposinf(np.diag(P)) if P.shape == (n, n) else np.zeros(n, bool)
    rest = P.copy() if P.shape == (n, n) else P
    if P.shape == (n, n):
        rest[diffuse, diffuse] = 0.0
    if (zbar.shape != (n,) or P.shape != (n, n) or not np.all(np.isfinite(rest))
            or not np.all(np.isfinite(zbar)) or np.any(rest[diffuse]) or np.any(rest[:, diffuse])):
        raise UserError(f"prior must be (mean ({n},), covariance ({n},{n})) of finite numbers "
                        "(an uncorrelated entry may have an infinite variance: no information)")
    info = np.zeros((n, n))
    keep = ~diffuse
    if keep.any():
        info[np.ix_(keep, keep)] = safe_inverse(P[np.ix_(keep, keep)])
    return zbar, info


def _initial_vector(initial, names, fixed, pose) -> np.ndarray:
    n = 6 + len(names)
    if initial is not None and not isinstance(initial, Mapping):
        z = np.asarray(initial, float).reshape(-1)
        if z.shape != (n,):
            raise UserError(f"initial must be a mapping or a vector of {n} numbers")
        return z.copy()
    initial = dict(initial or {})
    unknown = set(initial) - set(STATE_NAMES) - set(PARAM_NAMES)
    if unknown:
        raise UserError(f"unknown initial value(s): {', '.join(sorted(unknown))}")
    z = np.zeros(n)
    # the states are the centre of mass's: the first pose moved by the initial offset guess
    cx = float(initial.get("cx", fixed.get("cx", 0.0)))
    cy = float(initial.get("cy", fixed.get("cy", 0.0)))
    z[:3] = com_from_tracked(pose[0], cx, cy)
    for i, s in enumerate(STATE_NAMES):
        if s in initial:
            z[i] = float(initial[s])
    for j, name in enumerate(names):
        z[6 + j] = float(initial.get(name, fixed.get(name, DEFAULT_INITIAL[name])))
    return z


def _validate(pose_t, pose, cmd_t, thrust_n):
    pose_t = np.asarray(pose_t, float).reshape(-1)
    pose = np.asarray(pose, float)
    cmd_t = np.asarray(cmd_t, float).reshape(-1)
    thrust_n = np.asarray(thrust_n, float)
    if pose.ndim != 2 or pose.shape != (len(pose_t), 3):
        raise UserError(f"poses must be (N, 3) with N = {len(pose_t)} times, got {pose.shape}")
    if thrust_n.ndim != 2 or thrust_n.shape != (len(cmd_t), 4):
        raise UserError(f"thrusts must be ({len(cmd_t)}, 4), got {thrust_n.shape}")
    for name, a in (("pose times", pose_t), ("poses", pose), ("command times", cmd_t),
                    ("thrusts", thrust_n)):
        if not np.all(np.isfinite(a)):
            raise UserError(f"{name} contain NaN or infinity")
    if np.any(np.diff(pose_t) <= 0):
        raise UserError("pose times must increase strictly")
    if len(cmd_t) and np.any(np.diff(cmd_t) <= 0):
        raise UserError("command times must increase strictly")
    return pose_t, pose, cmd_t, thrust_n


LOG_PARAMS = ("mass", "izz")
"""Parameters solved for in log space (positive; a correction is a relative change)."""


class _Problem:
    """Residuals, cost and normal equations of one horizon (all poses up to a time).

    The solver works in internal coordinates ``q``: ``z`` with mass and Izz replaced
    by their logarithms (so they stay positive and a correction is relative).
    """

    def __init__(self, pose_t, pose, cmd_t, thrust_n, names, fixed, w, zbar, prior_info, max_step):
        self.pose_t, self.pose = pose_t, pose
        self.names, self.fixed, self.w = names, fixed, w
        self.zbar, self.prior_info = zbar, prior_info
        self.grid = make_grid(cmd_t, thrust_n, pose_t, max_step)
        self.islog = np.array([False] * 6 + [n in LOG_PARAMS for n in names])
        self._eval_cache = None
        self._stm_cache = None

    def to_z(self, q):
        z = np.array(q, dtype=float)
        with np.errstate(over="ignore"):
            z[self.islog] = np.exp(z[self.islog])
        return z

    def to_q(self, z):
        q = np.array(z, dtype=float)
        q[self.islog] = np.log(q[self.islog])
        return q

    def params(self, z) -> dict[str, float]:
        d = dict(self.fixed)
        d.update({n: float(v) for n, v in zip(self.names, z[6:], strict=True)})
        return d

    def evaluate(self, z):
        """``(cost, residuals (N,3), states (M,6))``; cost inf for an invalid point (cached)."""
        key = np.asarray(z, float).tobytes()
        if self._eval_cache is not None and self._eval_cache[0] == key:
            return self._eval_cache[1]
        out = self._evaluate(z)
        self._eval_cache = (key, out)
        return out

    def _evaluate(self, z):
        d = self.params(z)
        if not (np.all(np.isfinite(z)) and 0 < d["mass"] < 1e12 and 0 < d["izz"] < 1e12):
            return math.inf, None, None
        with np.errstate(all="ignore"):
            try:
                states = reference_states(z[:6], self.grid, d)
            except (OverflowError, ValueError):
                return math.inf, None, None
        if not np.all(np.isfinite(states)):
            return math.inf, None, None
        pred = tracked_pose(states[self.grid.node_pos], d.get("cx", 0.0), d.get("cy", 0.0))
        res = self.pose - pred
        res[:, 2] = wrap_angle(res[:, 2])
        cost = float(np.sum(res**2 * self.w))
        if self.prior_info is not None:
            dz = z - self.zbar
            cost += float(dz @ self.prior_info @ dz)
        return cost, res, states

    def stm(self, z, states):
        """(N, 6, 6+p) top rows of Phi(t_k, t0) along the reference trajectory ``states`` (cached)."""
        key = np.asarray(z, float).tobytes()
        if self._stm_cache is not None and self._stm_cache[0] == key:
            return self._stm_cache[1]
        with np.errstate(all="ignore"):
            _, phi = trajectory_stm(z[:6], None, None, self.pose_t, self.params(z), self.names,
                                    grid=self.grid, states=states)
        self._stm_cache = (key, phi)
        return phi

    def output_jacobian(self, z, states):
        """(N, 3, 6+p) d tracked pose(t_k) / dz at ``z`` (:func:`model.output_jacobian`)."""
        d = self.params(z)
        return output_jacobian(states[self.grid.node_pos], self.stm(z, states), self.names,
                               d.get("cx", 0.0), d.get("cy", 0.0))

    def normal(self, z, res, states):
        """``(Lambda, lambda)`` in z coordinates at ``z`` (Algorithm 1, steps 3-8)."""
        H = self.output_jacobian(z, states)
        sig = 1.0 / np.sqrt(self.w)
        Lam = fisher_information(H, sig[0], sig[2])
        lam = np.einsum("kin,i,ki->n", H, self.w, res, optimize=True)
        if self.prior_info is not None:
            Lam = Lam + self.prior_info
            lam = lam + self.prior_info @ (self.zbar - z)
        return Lam, lam

    def normal_q(self, z, Lam, lam):
        """Normal equations in q coordinates: ``D Lambda D``, ``D lambda`` with D = dz/dq."""
        D = np.where(self.islog, z, 1.0)
        return Lam * np.outer(D, D), lam * D


def _solve_scaled(Lam, lam, scale, mu):
    """Solve ``(Lambda + mu diag(Lambda)) dq = lambda`` in equilibrated scaled variables."""
    A = Lam * np.outer(scale, scale)
    b = lam * scale
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d) + mu * np.eye(len(d))
    try:
        y = np.linalg.solve(An, b / d)
    except np.linalg.LinAlgError:
        y = np.linalg.lstsq(An, b / d, rcond=1e-14)[0]
    if not np.all(np.isfinite(y)):
        y = np.linalg.lstsq(An, b / d, rcond=1e-12)[0]
    return y / d * scale  # unscaled step in q


STALL_RTOL = 1e-3
"""A step of the last stage that lowers the cost by less than this fraction of it, at a cost
above :data:`MISFIT_RATIO` times the noise's, counts towards a stall (the standard relative
cost-change criterion, applied where the model does not fit: a fit within the noise runs to
``tol`` as before)."""

STALL_STEPS = 3
"""Steps in a row that stall the fit (not converged: the model does not fit)."""

MISFIT_RATIO = RESIDUAL_RATIO**2
"""Cost per residual (in noise variances) above which the model does not fit: the residual
RMS :data:`RESIDUAL_RATIO` times the stated noise."""


def _lm(prob: _Problem, z, scale, tol_scaled, tol_sigma, max_iter, history, stats,
        reg: float = 0.0):
    """Levenberg-Marquardt / Gauss-Newton on one horizon.

    ``reg`` > 0 adds a pseudo-prior of that information on the log-parameters about
    their starting values (used on the short horizons of the start-up only, where a
    parameter can be unobservable). Steps are shortened so no log-parameter changes
    by more than 1 (a factor e) per iteration.

    Returns ``(z, converged, Lambda_z, Lambda_q (with reg), residuals, states)``.
    """
    q_anchor = prob.to_q(z)
    wreg = np.where(prob.islog, reg, reg / scale**2)
    wreg[:6] = 0.0

    def total(c, q):
        return c + float(np.sum(wreg * (q - q_anchor) ** 2))

    cost, res, states = prob.evaluate(z)
    if not math.isfinite(cost):
        raise UserError("the initial guess gives a non-finite trajectory (check mass and Izz > 0)")
    history.append(cost)
    q = prob.to_q(z)
    cost = total(cost, q)
    mu = 0.0
    Lam, lam = prob.normal(z, res, states)
    Lq = None
    for _ in range(max_iter):
        if not (np.all(np.isfinite(Lam)) and np.all(np.isfinite(lam))):
            return z, False, Lam, Lq, res, states
        Lq, lq = prob.normal_q(z, Lam, lam)
        Lq = Lq + np.diag(wreg)
        lq = lq - wreg * (q - q_anchor)
        step = _solve_scaled(Lq, lq, scale, mu)
        big = np.max(np.abs(step[prob.islog]), initial=0.0)
        if big > 1.0:
            step = step / big
        small = bool(np.max(np.abs(step / scale)) < tol_scaled)
        if tol_sigma is not None and mu == 0.0:
            sig = np.sqrt(np.maximum(np.diag(safe_inverse(Lq)), 1e-300))
            small = small or bool(np.max(np.abs(step) / sig) < tol_sigma)
        q_new = q + step
        z_new = prob.to_z(q_new)
        if small and tol_sigma is not None:
            # an intermediate stage: the next, longer horizon re-evaluates this point
            stats["iterations"] += 1
            return z_new, True, Lam, Lq, res, states
        cost_new, res_new, states_new = prob.evaluate(z_new)
        cost_new = total(cost_new, q_new)
        if small:
            if cost_new <= cost * (1 + 1e-12) + 1e-12:
                z, q, cost, res, states = z_new, q_new, cost_new, res_new, states_new
                stats["iterations"] += 1
                history.append(cost)
            return z, True, Lam, Lq, res, states
        if cost_new <= cost:
            # the last stage stalls when a fit far from the noise (the model does not fit)
            # gains less than STALL_RTOL of its cost STALL_STEPS steps in a row
            crawl = (tol_sigma is None and cost - cost_new < STALL_RTOL * cost
                     and cost_new > MISFIT_RATIO * 3 * len(prob.pose_t))
            stats["crawl"] = stats.get("crawl", 0) + 1 if crawl else 0
            z, q, cost, res, states = z_new, q_new, cost_new, res_new, states_new
            stats["iterations"] += 1
            history.append(cost)
            if stats["crawl"] >= STALL_STEPS:
                stats["stalled"] = cost / (3 * len(prob.pose_t))
                return z, False, Lam, Lq, res, states
            mu = 0.0 if mu < 1e-6 else mu / 10.0
            Lam, lam = prob.normal(z, res, states)
        else:
            mu = 1e-4 if mu == 0.0 else mu * 10.0
            stats["rejected"] += 1
            if mu > 1e10:
                return z, False, Lam, Lq, res, states
    return z, False, Lam, Lq, res, states


def _first_horizon(t_rel, pose, horizon0_s, yaw_limit_rad=1.0, min_poses=12):
    """First horizon: ``horizon0_s`` or earlier, when the measured yaw has turned by 1 rad."""
    yaw = np.unwrap(pose[:, 2])
    turned = np.nonzero(np.abs(yaw - yaw[0]) > yaw_limit_rad)[0]
    h = float(horizon0_s)
    if turned.size:
        h = min(h, float(t_rel[turned[0]]))
    return max(h, float(t_rel[min(min_poses, len(t_rel) - 1)]))


def _next_horizon(h, span, z, Lam_q, full: _Problem, t_rel_full, yaw_3sigma_rad=1.0):
    """Longest horizon (at least 2h) where the predicted yaw's 3 sigma stays below the limit."""
    cost, _, states = full.evaluate(z)
    if not math.isfinite(cost) or Lam_q is None:
        return min(2 * h, span)
    phi = full.stm(z, states)
    P = safe_inverse(Lam_q)
    hy = phi[:, 2, :] * np.where(full.islog, z, 1.0)  # d psi / d q
    with np.errstate(all="ignore"):
        var = np.einsum("kn,nm,km->k", hy, P, hy)
    bad = np.nonzero(~(3 * np.sqrt(np.abs(var)) < yaw_3sigma_rad) & (t_rel_full > h))[0]
    limit = span if bad.size == 0 else float(t_rel_full[bad[0]])
    nxt = max(2 * h, limit)
    return span if nxt >= 0.75 * span else nxt


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
    pose_t, pose, cmd_t, thrust_n = _validate(pose_t, pose, cmd_t, thrust_n)
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
    z = _initial_vector(initial, names, fixed_d, pose)
    zbar, prior_info = _as_prior(prior, n)
    for j, name in enumerate(names):
        if name in LOG_PARAMS and not z[6 + j] > 0:
            raise UserError(f"initial {name} must be positive, got {z[6 + j]:g}")
    if not np.all(np.isfinite(z)):
        raise UserError("initial values must be finite")
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    scale = np.concatenate([STATE_SCALE, [1.0 if n in LOG_PARAMS else PARAM_SCALE[n] for n in names]])
    t_rel = pose_t - pose_t[0]
    span = float(t_rel[-1])
    full = _Problem(pose_t, pose, cmd_t, thrust_n, names, fixed_d, w, zbar, prior_info, max_step)
    h = span if horizon0_s is None or horizon0_s <= 0 else _first_horizon(t_rel, pose, horizon0_s)
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
            prob = _Problem(pose_t[keep], pose[keep], cmd_t, thrust_n, names, fixed_d, w, zbar,
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
        h = _next_horizon(h, span, z, Lq, full, t_rel)
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
                       horizons, time.perf_counter() - t_start, Lam, warnings)


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

"""The batch least-squares problem of one horizon and its solver (used by
:func:`estimator.batch.least_squares.batch_ls`).

:class:`HorizonProblem` holds the residuals, cost and normal equations of the poses up to a
time; :func:`levenberg_marquardt` iterates damped Gauss-Newton steps on it in scaled
internal coordinates (mass and Izz in log space); :func:`first_horizon` and
:func:`next_horizon` choose the growing horizon's stages. The inputs are checked and the
prior and start vector formed by :func:`validate_inputs`, :func:`as_prior` and
:func:`initial_vector`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from common.errors import UserError
from estimator.batch.crlb import (
    fisher_information,
    make_grid,
    reference_states,
    safe_inverse,
    trajectory_stm,
)
from estimator.batch.plausibility import RESIDUAL_RATIO
from estimator.plant.model import PARAM_NAMES, STATE_NAMES, wrap_angle
from estimator.plant.output import com_from_tracked, output_jacobian, tracked_pose

DEFAULT_INITIAL = {"mass": 1.0, "izz": 0.005, "ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0,
                   "ay": 0.0, "cx": 0.0, "cy": 0.0}
"""The paper's initial guess (m = 1 kg, Izz = 0.005 kg m^2); friction, tilt and the centre
of mass's offset from the tracked origin zero."""


def as_prior(prior, n: int):
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


def initial_vector(initial, names, fixed, pose) -> np.ndarray:
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


def validate_inputs(pose_t, pose, cmd_t, thrust_n):
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


class HorizonProblem:
    """Residuals, cost and normal equations of one horizon (all poses up to a time).

    The solver works in internal coordinates ``q``: ``z`` with mass and Izz replaced
    by their logarithms (so they stay positive and a correction is relative).
    """

    def __init__(self, pose_t, pose, cmd_t, thrust_n, names, fixed, w, zbar, prior_info, max_step):
        self.pose_t, self.pose = pose_t, pose
        self.names, self.fixed, self.w = names, fixed, w
        self.zbar, self.prior_info = zbar, prior_info
        self.max_step = max_step
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
        """(N, 3, 6+p) d tracked pose(t_k) / dz at ``z`` (:func:`estimator.plant.output.output_jacobian`)."""
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


def solve_scaled(Lam, lam, scale, mu):
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


def levenberg_marquardt(prob: HorizonProblem, z, scale, tol_scaled, tol_sigma, max_iter, history, stats,
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
        step = solve_scaled(Lq, lq, scale, mu)
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


def first_horizon(t_rel, pose, horizon0_s, yaw_limit_rad=1.0, min_poses=12):
    """First horizon: ``horizon0_s`` or earlier, when the measured yaw has turned by 1 rad."""
    yaw = np.unwrap(pose[:, 2])
    turned = np.nonzero(np.abs(yaw - yaw[0]) > yaw_limit_rad)[0]
    h = float(horizon0_s)
    if turned.size:
        h = min(h, float(t_rel[turned[0]]))
    return max(h, float(t_rel[min(min_poses, len(t_rel) - 1)]))


def next_horizon(h, span, z, Lam_q, full: HorizonProblem, t_rel_full, yaw_3sigma_rad=1.0):
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

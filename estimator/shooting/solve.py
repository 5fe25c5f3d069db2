"""Levenberg-Marquardt on the block-arrow normal equations of a multiple-shooting problem,
and the covariances of its shared parameters.

The normal matrix of a run cut into S segments is block-arrow: a 6x6 block per segment
(its own initial state), a p x p block of the shared parameters and the coupling between
each segment and them. Eliminating the segments' blocks (the Schur complement) leaves a
p x p system, so a step costs O(S) and the whole fit grows linearly with the run.

Hand-written rather than ``scipy.optimize.least_squares`` (``trf`` with the same sparse
Jacobian, ``lsmr``): the same mass to 1e-5, 1.5-2.3x faster on the paper's run by 24
segments (``make bench``, row "Schur LM against scipy least_squares"), and the reduced
blocks it keeps are what the covariances below are made of.

Covariances of the shared parameters (all from the same reduced quantities):

- ``noise``: the inverse Schur complement, (J^T J)^-1 in noise units: what the stated pose
  noise alone allows. It assumes the model is right and the residuals white.
- ``clustered``: the segment-clustered sandwich S^-1 (sum_s h_s h_s^T) S^-1 with
  ``h_s`` segment s's score with its own initial state partialled out, from statsmodels'
  ``S_crosssection`` (the meat of its ``cov_cluster``) and ``cov_cluster``'s small-sample
  correction. Errors that are correlated within a segment (an unmodelled force, a wrong
  dead time) are not counted as independent information.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from estimator.shooting.problem import ShootingProblem

DEBUG = bool(os.environ.get("TPODS_LM_DEBUG"))


@dataclass
class ReducedNormal:
    """The Schur-reduced normal equations at one point.

    Attributes:
        schur: (p, p) S = G - sum_s C_s^T D_s^-1 C_s.
        rhs: (p,) the reduced gradient.
        d_inv: (S, 6, 6) inverse segment blocks; c: (S, 6, p) couplings; bs: (S, 6).
    """

    schur: np.ndarray
    rhs: np.ndarray
    d_inv: np.ndarray
    c: np.ndarray
    bs: np.ndarray


@dataclass
class NormalBlocks:
    """The blocks of J^T J and J^T r at one point: per segment D (S, 6, 6), C (S, 6, p),
    bs (S, 6); shared G (p, p), bg (p,)."""

    D: np.ndarray
    C: np.ndarray
    bs: np.ndarray
    G: np.ndarray
    bg: np.ndarray


def normal_blocks(prob: ShootingProblem, r: np.ndarray, Js: np.ndarray, Jg: np.ndarray
                  ) -> NormalBlocks:
    """The blocks, one small matrix product per segment (rows are in segment order)."""
    S, p = prob.n_seg, Jg.shape[1]
    D, C, bs = np.empty((S, 6, 6)), np.empty((S, 6, p)), np.empty((S, 6))
    for k in range(S):
        a, b = prob.row_start[k], prob.row_start[k + 1]
        js = Js[a:b]
        D[k] = js.T @ js
        C[k] = js.T @ Jg[a:b]
        bs[k] = js.T @ r[a:b]
    return NormalBlocks(D, C, bs, Jg.T @ Jg, Jg.T @ r)


def reduce_normal(prob: ShootingProblem, r: np.ndarray, Js: np.ndarray, Jg: np.ndarray,
                  damping: float = 0.0, blocks: NormalBlocks | None = None) -> ReducedNormal:
    """The damped (Marquardt: ``damping * diag``) reduced system of the Gauss-Newton step
    (``blocks``: :func:`normal_blocks` of the same point, when already formed)."""
    nb = blocks if blocks is not None else normal_blocks(prob, r, Js, Jg)
    D = nb.D
    Dd = D + damping * np.einsum("sii->si", D)[:, :, None] * np.eye(6)[None] + 1e-12 * np.eye(6)
    try:
        d_inv = np.linalg.inv(Dd)
    except np.linalg.LinAlgError:
        d_inv = np.linalg.pinv(Dd)
    dc = d_inv @ nb.C  # (S, 6, p)
    schur = nb.G - np.einsum("sip,siq->pq", nb.C, dc)
    schur = schur + damping * np.diag(np.diag(nb.G))
    rhs = nb.bg - np.einsum("sip,si->p", dc, nb.bs)
    return ReducedNormal(schur, rhs, d_inv, nb.C, nb.bs)


def partialled_scores(prob: ShootingProblem, r: np.ndarray, Js: np.ndarray, Jg: np.ndarray
                      ) -> np.ndarray:
    """(R, p) every residual row's score with its own segment's initial state partialled
    out: (Jg_row - Js_row D_s^-1 C_s) r_row (what the clustered sandwich sums)."""
    red = reduce_normal(prob, r, Js, Jg)
    out = np.empty_like(Jg)
    for k in range(prob.n_seg):
        a, b = prob.row_start[k], prob.row_start[k + 1]
        out[a:b] = (Jg[a:b] - Js[a:b] @ (red.d_inv[k] @ red.c[k])) * r[a:b, None]
    return out


def solve_step(red: ReducedNormal) -> tuple[np.ndarray, np.ndarray]:
    """``(d theta (p,), d s0 (S, 6))`` of the reduced system (equilibrated)."""
    A = red.schur
    if A.size == 0:  # no shared parameter: every segment's own 6x6 system
        ds = np.einsum("sij,sj->si", red.d_inv, red.bs)
        return np.zeros(0), -ds
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    try:
        y = np.linalg.solve(An, red.rhs / d)
    except np.linalg.LinAlgError:
        y = np.linalg.lstsq(An, red.rhs / d, rcond=1e-12)[0]
    dg = y / d
    ds = np.einsum("sij,sj->si", red.d_inv, red.bs - red.c @ dg)
    return -dg, -ds  # J is d residual / d unknown: the Gauss-Newton step is -(J^T J)^-1 J^T r


def safe_inv(A: np.ndarray) -> np.ndarray:
    if A.size == 0:
        return A.copy()
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    try:
        return np.linalg.inv(A / np.outer(d, d)) / np.outer(d, d)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(A / np.outer(d, d)) / np.outer(d, d)


@dataclass
class LMResult:
    s0: np.ndarray
    theta: np.ndarray
    r: np.ndarray
    cost: float
    converged: bool
    iterations: int
    message: str
    Js: np.ndarray = field(repr=False, default=None)
    Jg: np.ndarray = field(repr=False, default=None)


def levenberg_marquardt(prob: ShootingProblem, s0: np.ndarray, theta: np.ndarray,
                        max_iter: int = 60, tol: float = 1e-3, rtol: float = 1e-10,
                        max_log_step: float = 0.7) -> LMResult:
    """Minimise the sum of squared residuals over every segment's state and ``theta``.

    Converged when the largest step of a shared parameter is below ``tol`` of its sigma (in
    noise units) or the cost's relative fall below ``rtol``. No log parameter moves by more
    than ``max_log_step`` in one step."""
    s0 = np.array(s0, float)
    theta = np.array(theta, float)
    r, Js, Jg = prob.jacobian(s0, theta)
    cost = float(r @ r)
    if not math.isfinite(cost):
        return LMResult(s0, theta, r, cost, False, 0, "the start gives a non-finite trajectory",
                        Js, Jg)
    mu = 1e-3
    it = 0
    blocks = normal_blocks(prob, r, Js, Jg)
    msg = f"not converged after {max_iter} iterations"
    converged = False
    while it < max_iter:
        it += 1
        red = reduce_normal(prob, r, Js, Jg, mu, blocks)
        dg, ds = solve_step(red)
        big = np.max(np.abs(dg[prob.islog]), initial=0.0)
        if big > max_log_step:
            dg, ds = dg * (max_log_step / big), ds * (max_log_step / big)
        th_new, s_new = theta + dg, s0 + ds
        r_new = prob.residuals(s_new, th_new)[0]
        cost_new = float(r_new @ r_new)
        if math.isfinite(cost_new) and cost_new <= cost:
            sig = np.sqrt(np.maximum(np.diag(safe_inv(reduce_normal(prob, r, Js, Jg, 0.0,
                                                                    blocks).schur)), 1e-300))
            small = bool(len(dg) and np.all(np.abs(dg) <= tol * sig))
            if DEBUG:
                print(it, cost_new, mu, float(np.max(np.abs(dg) / sig)) if len(dg) else 0)
            # a stalled fall counts only undamped: a heavily damped step is short, not final
            fell = (cost - cost_new) <= rtol * cost and mu < 1e-2
            theta, s0, cost = th_new, s_new, cost_new
            mu = max(mu / 5.0, 1e-9)
            r, Js, Jg = prob.jacobian(s0, theta)
            blocks = normal_blocks(prob, r, Js, Jg)
            cost = float(r @ r)
            if small or fell:
                converged = True
                msg = "converged"
                break
        else:
            mu *= 8.0
            if mu > 1e10:
                msg = f"not converged: no step lowers the cost after {it} iterations"
                break
    return LMResult(s0, theta, r, cost, converged, it, msg, Js, Jg)


def covariances(prob: ShootingProblem, lm: LMResult) -> dict[str, np.ndarray]:
    """``{"noise", "clustered"}`` (p, p) covariances of the shared parameters at the
    solution, in the fit's coordinates (log for mass and Izz; module doc)."""
    from statsmodels.stats.sandwich_covariance import S_crosssection

    red = reduce_normal(prob, lm.r, lm.Js, lm.Jg)
    inv = safe_inv(red.schur)
    seg_of_row = np.repeat(np.arange(prob.n_seg), np.diff(prob.row_start))
    meat = S_crosssection(partialled_scores(prob, lm.r, lm.Js, lm.Jg), seg_of_row)
    n_groups = prob.n_seg
    n_obs = len(lm.r)
    k = len(prob.names) + 6 * prob.n_seg
    # statsmodels cov_cluster(use_correction=True): G/(G-1) * (N-1)/(N-K)
    corr = (n_groups / max(n_groups - 1, 1)) * ((n_obs - 1) / max(n_obs - k, 1))
    clustered = corr * inv @ meat @ inv
    return {"noise": inv, "clustered": clustered}

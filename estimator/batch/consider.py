"""The consider covariance: what the thrust table's uncertainty adds to an estimate.

The batch estimate ``z`` (initial state and parameters) solves the normal equations
``Lambda dz = sum_k H_k^T W r_k``. A small error ``dc`` in the thrust table's parameters
``c`` (:func:`common.thrust_uncertainty.thrust_sensitivity`) shifts the predicted poses by
``J_k dc`` and so the estimate by ``S dc`` with

    S = Lambda^-1 sum_k H_k^T W J_k        (6+p, P)

and the covariance it adds is ``S P_c S^T`` (a "consider" covariance: the parameters are
not estimated, their uncertainty is carried). Total = noise part ``Lambda^-1`` + thrust part.

``J_k`` comes from the same linearisation as ``H_k``: on every segment of the fit's grid
(constant thrust, one RK4 step) the state moves as ``x+ = Phi_e x + Gamma_e dT_e``, where
``Gamma_e = d x+/d T`` is the RK4 step's exact response to its four thrusts and ``dT_e``
the segment's thrust change ``(4, P)``; the affine recursion is evaluated as a blocked
scan (vectorised over blocks of about sqrt(M) segments). No finite differences.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from estimator.batch.crlb import (
    DEFAULT_MAX_STEP_S,
    Grid,
    make_grid,
    reference_states,
    trajectory_stm,
)
from estimator.plant.model import (
    ARM_M,
    PARAM_NAMES,
    SQRT1_2,
    active_effects,
    array_function,
    jacobian_pattern,
    wrench,
)
from estimator.plant.output import output_jacobian
from estimator.plant.segments import segment_thrust


def thrust_input_matrix(mass: float, izz: float, arm: float = ARM_M) -> np.ndarray:
    """(6, 4) ``d xdot / d T``: how each thruster's force enters the state derivative."""
    G = np.zeros((6, 4))
    G[3] = np.array([-1.0, 1.0, 1.0, -1.0]) * SQRT1_2 / mass
    G[4] = np.array([1.0, 1.0, -1.0, -1.0]) * SQRT1_2 / mass
    G[5] = np.array([1.0, -1.0, 1.0, -1.0]) * arm / izz
    return G


def segment_maps(states: np.ndarray, grid: Grid, params: Mapping[str, float]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per segment of ``grid``: the RK4 step's state transition ``Phi (M-1, 6, 6)`` and its
    response to the segment's thrusts ``Gamma (M-1, 6, 4)``, along ``states`` (M, 6)."""
    kw = {k: float(v) for k, v in params.items()}
    h = np.diff(grid.events)[:, None, None]
    s = states[:-1]
    T = grid.seg_thrust
    G = thrust_input_matrix(kw["mass"], kw["izz"], kw.get("arm", ARM_M))
    # rates and state Jacobian in one call of the compiled plant (the effects present only)
    eff = active_effects(kw)
    f = array_function(eff, ())
    pattern = jacobian_pattern(eff, ())
    w = wrench(T, kw.get("arm", ARM_M))
    pv = [kw.get(k, 0.0) for k in PARAM_NAMES]

    def rate(x):
        rates, vals = f(x[:, 2], x[:, 3], x[:, 4], x[:, 5], w[:, 0], w[:, 1], w[:, 2], *pv)
        sdot = np.empty_like(x)
        for i, v in enumerate(rates):
            sdot[:, i] = v
        A = np.zeros((len(x), 6, 6))
        for (i, j), v in zip(pattern, vals, strict=True):
            A[:, i, j] = v
        return sdot, A

    hv = h[:, :, 0]
    k1, A1 = rate(s)
    s2 = s + 0.5 * hv * k1
    k2, A2 = rate(s2)
    s3 = s + 0.5 * hv * k2
    k3, A3 = rate(s3)
    s4 = s + hv * k3
    _, A4 = rate(s4)
    eye = np.eye(6)
    d1 = A1
    d2 = A2 @ (eye + 0.5 * h * d1)
    d3 = A3 @ (eye + 0.5 * h * d2)
    d4 = A4 @ (eye + h * d3)
    phi = eye + h / 6.0 * (d1 + 2 * d2 + 2 * d3 + d4)
    g1 = np.broadcast_to(G, (len(s), 6, 4))
    g2 = A2 @ (0.5 * h * g1) + G
    g3 = A3 @ (0.5 * h * g2) + G
    g4 = A4 @ (h * g3) + G
    gamma = h / 6.0 * (g1 + 2 * g2 + 2 * g3 + g4)
    return phi, gamma


def affine_scan(phi: np.ndarray, inp: np.ndarray, node_pos: np.ndarray) -> np.ndarray:
    """``X`` at the nodes for ``X_0 = 0``, ``X_{e+1} = phi_e X_e + inp_e``.

    Args:
        phi: (M-1, 6, 6); inp: (M-1, 6, P); node_pos: (N,) boundary index of each node.

    Returns:
        (N, 6, P).
    """
    m1, n, P = inp.shape
    node_pos = np.asarray(node_pos)
    out = np.zeros((len(node_pos), n, P))
    if m1 == 0 or P == 0:
        return out
    L = max(1, int(math.sqrt(m1)))
    nb = -(-m1 // L)
    Pb = np.empty((nb * L, n, n))
    Pb[:m1] = phi
    Pb[m1:] = np.eye(n)
    Bb = np.zeros((nb * L, n, P))
    Bb[:m1] = inp
    Pb = Pb.reshape(nb, L, n, n)
    Bb = Bb.reshape(nb, L, n, P)
    # prefix compositions inside each block: (Phi_j...Phi_0, X after j from X=0 at block start)
    preP = np.empty_like(Pb)
    preB = np.empty_like(Bb)
    preP[:, 0] = Pb[:, 0]
    preB[:, 0] = Bb[:, 0]
    for j in range(1, L):
        np.matmul(Pb[:, j], preP[:, j - 1], out=preP[:, j])
        preB[:, j] = Pb[:, j] @ preB[:, j - 1] + Bb[:, j]
    start = np.zeros((nb, n, P))  # X at the start of each block
    for b in range(1, nb):
        start[b] = preP[b - 1, L - 1] @ start[b - 1] + preB[b - 1, L - 1]
    later = node_pos > 0
    seg = node_pos[later] - 1  # the last segment ending at the node
    bi, ji = seg // L, seg % L
    out[later] = preP[bi, ji] @ start[bi] + preB[bi, ji]
    return out


def output_sensitivity(states: np.ndarray, grid: Grid, params: Mapping[str, float],
                       seg_dthrust: np.ndarray) -> np.ndarray:
    """(N, 3, P) ``d pose(t_k) / d c`` at the grid's nodes for thrust derivatives
    ``seg_dthrust`` (M-1, 4, P) per segment (N per unit of each parameter)."""
    phi, gamma = segment_maps(states, grid, params)
    inp = gamma @ seg_dthrust
    return affine_scan(phi, inp, grid.node_pos)[:, :3, :]


def segment_jacobian(grid: Grid, cmd_jacobian: np.ndarray) -> np.ndarray:
    """(M-1, 4, P) per-segment thrust derivatives from per-command-row ones (Nc, 4, P)
    (zero before the first command)."""
    cmd_t = grid.cmd_t
    idx = np.searchsorted(cmd_t, grid.events[:-1], side="right") - 1
    Nc, C, P = cmd_jacobian.shape
    flat = segment_thrust(cmd_jacobian.reshape(Nc, C * P), idx)
    return flat.reshape(-1, C, P)


@dataclass
class ConsiderResult:
    """The thrust table's contribution to an estimate's covariance.

    Attributes:
        names: (P,) the table's uncertain parameters (see ``thrust_sensitivity``).
        sensitivity: (n, P) ``S = Lambda^-1 sum_k H_k^T W J_k`` (SI units per parameter
            unit): a change ``dc`` of the parameters moves the estimate by ``-S dc`` (the
            covariance ``S P_c S^T`` does not depend on the sign).
        cov_thrust: (n, n) ``S P_c S^T``.
        contributions: (n, P) each parameter's share of each estimate's variance (sums
            to ``diag(cov_thrust)`` when the parameters are uncorrelated; with correlated
            parameters their covariance is shared out by rows of ``P_c``).
    """

    names: tuple[str, ...]
    sensitivity: np.ndarray
    cov_thrust: np.ndarray
    contributions: np.ndarray


def consider(H: np.ndarray, weights: np.ndarray, cov_noise: np.ndarray, J: np.ndarray,
             P_c: np.ndarray, names: tuple[str, ...]) -> ConsiderResult:
    """The consider covariance of a least-squares estimate.

    Args:
        H: (N, 3, n) output sensitivity to the estimated vector (top rows of Phi).
        weights: (3,) or (N, 3) inverse measurement variances.
        cov_noise: (n, n) ``Lambda^-1`` (may hold inf for a direction without information).
        J: (N, 3, P) output sensitivity to the considered parameters.
        P_c: (P, P) their covariance.
    """
    n = H.shape[-1]
    P = J.shape[-1]
    if P == 0:
        z = np.zeros((n, 0))
        return ConsiderResult(names, z, np.zeros((n, n)), z)
    w = np.broadcast_to(np.asarray(weights, float), H.shape[:2])
    b = np.einsum("kin,ki,kip->np", H, w, J, optimize=True)
    finite = np.all(np.isfinite(cov_noise))
    if finite:
        S = cov_noise @ b
    else:
        S = np.full((n, P), np.nan)
    cov = S @ P_c @ S.T
    contrib = S * (S @ P_c)
    return ConsiderResult(names, S, 0.5 * (cov + cov.T), contrib)


NO_UNCERTAINTY = ("the thrust table states no uncertainty, so sigma covers measurement noise "
                  "only (add [uncertainty] scale_rel, or use a table from 'tpods bench fit')")
THRUSTS_GIVEN = ("thrusts.csv gives the thrusts in newtons: no thrust-table uncertainty is "
                 "included, sigma covers measurement noise only")


def _fit_reference(res, cmd_t: np.ndarray, thrust_n: np.ndarray, max_step: float
                   ) -> tuple[Grid, np.ndarray]:
    """The grid and reference trajectory of ``res`` at its estimate: the fit's own when it
    kept them for the same commands, thrusts, poses and step (the same numbers), else
    integrated again."""
    ref = getattr(res, "reference", None)
    if ref is not None:
        grid, states, pose_t, step, z0, params = ref
        if (step == max_step and pose_t is res.t and np.array_equal(z0, res.z0)
                and params == res.params and np.array_equal(grid.cmd_t, cmd_t)
                and np.array_equal(grid.thrust_n, thrust_n)):
            return grid, states
    grid = make_grid(cmd_t, thrust_n, res.t, max_step)
    return grid, reference_states(res.z0[:6], grid, res.params)


def batch_consider(res, cmd_t: np.ndarray, sens, *, sigma_pos_m: float, sigma_yaw_rad: float,
                   max_step: float = DEFAULT_MAX_STEP_S) -> ConsiderResult:
    """The thrust part of a batch fit's covariance at its estimate.

    Args:
        res: a :class:`estimator.batch.least_squares.BatchResult` (its poses ``t``, estimate
            ``z0``, ``params`` and noise covariance).
        cmd_t: (Nc,) command times; sens: :class:`common.thrust_uncertainty.ThrustSensitivity`
            of the same command rows.
        sigma_pos_m, sigma_yaw_rad: the fit's measurement noise.
    """
    s0 = res.z0[:6]
    with np.errstate(all="ignore"):
        grid, states = _fit_reference(res, cmd_t, sens.thrust_n, max_step)
        _, phi = trajectory_stm(s0, None, None, res.t, res.params, res.names, grid=grid,
                                states=states)
        J = _tracked_output(states, grid, res.params, sens)
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    cov_noise = res.cov if res.cov_noise is None else res.cov_noise
    cx, cy = float(res.params.get("cx", 0.0)), float(res.params.get("cy", 0.0))
    H = output_jacobian(states[grid.node_pos], phi, res.names, cx, cy)
    return consider(H, w, cov_noise, J, sens.covariance, sens.names)


def _tracked_output(states: np.ndarray, grid: Grid, params: Mapping[str, float], sens
                    ) -> np.ndarray:
    """(N, 3, P) d tracked pose(t_k) / d considered parameter along ``states`` (the
    tracked frame's poses: the yaw rotates the centre of mass offset)."""
    J = output_sensitivity(states, grid, params, segment_jacobian(grid, sens.jacobian))
    cx, cy = float(params.get("cx", 0.0)), float(params.get("cy", 0.0))
    return output_jacobian(states[grid.node_pos], J, (), cx, cy)


def considered_output(pose_t: np.ndarray, cmd_t: np.ndarray, sens, params: Mapping[str, float],
                      s0, max_step: float = DEFAULT_MAX_STEP_S) -> np.ndarray:
    """(N, 3, P) d tracked pose(t_k) / d considered parameter of ``sens`` (a
    ThrustSensitivity on the rows ``cmd_t``) at the plant ``params`` from the state
    ``s0``: the ``J_k`` of :func:`consider` for a caller with its own ``H_k``."""
    grid = make_grid(cmd_t, sens.thrust_n, pose_t, max_step)
    with np.errstate(all="ignore"):
        states = reference_states(np.asarray(s0, float), grid, params)
        return _tracked_output(states, grid, params, sens)


def bound_consider(pose_t: np.ndarray, cmd_t: np.ndarray, sens, params: Mapping[str, float],
                   s0, names, *, sigma_pos_m: float, sigma_yaw_rad: float,
                   max_step: float = DEFAULT_MAX_STEP_S) -> ConsiderResult:
    """The thrust part of the covariance of an efficient estimate (the Cramér-Rao bound's
    companion): ``S P_c S^T`` with ``S = F^-1 sum_k H_k^T W J_k`` at the plant ``params``.
    Indices as the augmented vector (6 states, then ``names``)."""
    from estimator.batch.crlb import fisher_information, safe_inverse

    grid = make_grid(cmd_t, sens.thrust_n, pose_t, max_step)
    s0 = np.asarray(s0, float)
    states = reference_states(s0, grid, params)
    _, phi = trajectory_stm(s0, None, None, pose_t, params, tuple(names), grid=grid, states=states)
    J = _tracked_output(states, grid, params, sens)
    cx, cy = float(params.get("cx", 0.0)), float(params.get("cy", 0.0))
    H = output_jacobian(states[grid.node_pos], phi, tuple(names), cx, cy)
    F = fisher_information(H, sigma_pos_m, sigma_yaw_rad)
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    return consider(H, w, safe_inverse(F), J, sens.covariance, sens.names)

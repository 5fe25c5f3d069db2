"""Sensitivities (Eqs. 16-18), Fisher information and the Cramér-Rao bound.

The augmented state is ``z = (x, y, psi, u, v, r, theta)`` with ``theta`` the
parameters named in ``names`` (any subset of ``model.PARAM_NAMES``). Its transition
matrix ``Phi(t, t0) = dz(t)/dz(t0)`` holds the state sensitivities to the initial
state (first 6 columns) and to the parameters, ``S_x,theta`` (last p columns, the
solution of Eq. 17 with ``S(t0) = 0``). The output is the pose ``y = (x, y, psi)``,
so ``H = [I_3 0]``, ``dH/dtheta = 0`` and ``S_y,theta = S_x,theta[:3]`` (Eq. 18).

Propagation (:func:`trajectory_stm`) splits the time line at every pose and every
command switch and at most ``max_step`` apart, integrates the reference trajectory
with the fused scalar RK4 of :func:`model.rk4_hold_chain` (one step per segment), then
propagates every segment's transition matrix at once with :func:`propagate.rk4_stm`
(the same RK4 step, vectorised over segments) and chains them.

The Fisher information of the pose measurements with white noise of standard
deviations ``(sigma_pos, sigma_pos, sigma_yaw)`` is ``F = sum_k H_k^T R^-1 H_k`` with
``H_k = [I_3 0] Phi(t_k, t0)``. The initial state is a nuisance: the bound on the
parameters is the inverse of the Schur complement
``F_tt - F_ts F_ss^-1 F_st`` (equal to the parameter block of ``F^-1``).

A vehicle's input parameters (valve dead time ``delay``, shared-supply ``drop``) join the
bound in :func:`estimator.batch.input_params.crlb_input_params` (the same Fisher matrix
with their finite-difference columns; the fit's Jacobian).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from common.errors import UserError
from estimator.plant.model import ARM_M, PARAM_NAMES, PlantParams, rk4_hold_chain, wrench
from estimator.plant.output import output_jacobian
from estimator.plant.propagate import rk4_stm
from estimator.plant.segments import segment_thrust, zoh_segments

STATE_SCALE = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
"""Characteristic size of x, y (m), psi (rad), u, v (m/s), r (rad/s)."""

PARAM_SCALE = {"mass": 1.0, "izz": 1e-3, "ct": 0.1, "cr": 1e-3, "kb": 1e-3, "ax": 1e-2,
               "ay": 1e-2, "cx": 1e-2, "cy": 1e-2}
"""Characteristic size of each parameter in SI units (kg, kg m^2, N s/m, ...)."""

DEFAULT_MAX_STEP_S = 0.01


def plant_from(params: Mapping[str, float]) -> PlantParams:
    """PlantParams from model keyword names (mass, izz, arm, ct, cr, kb, ax, ay, cx, cy)."""
    return PlantParams(float(params["mass"]), float(params["izz"]),
                       float(params.get("arm", ARM_M)), float(params.get("ct", 0.0)),
                       float(params.get("cr", 0.0)), float(params.get("kb", 0.0)),
                       float(params.get("ax", 0.0)), float(params.get("ay", 0.0)),
                       float(params.get("cx", 0.0)), float(params.get("cy", 0.0)))


def check_names(names: Sequence[str]) -> tuple[str, ...]:
    names = tuple(names)
    bad = [n for n in names if n not in PARAM_NAMES]
    if bad:
        raise UserError(f"unknown parameter(s) {', '.join(bad)}; choose from {', '.join(PARAM_NAMES)}")
    if len(set(names)) != len(names):
        raise UserError(f"parameter names repeat: {', '.join(names)}")
    return names


@dataclass
class Grid:
    """The segment grid of a trajectory (see :func:`make_grid`)."""

    events: np.ndarray      # (M,) boundary times, s
    seg_thrust: np.ndarray  # (M-1, 4) thrust on each segment, N
    node_pos: np.ndarray    # (N,) index of each node (pose time) in events
    cmd_t: np.ndarray
    thrust_n: np.ndarray
    _lists: dict = field(default_factory=dict, repr=False, compare=False)

    def chain_inputs(self, arm_m: float) -> tuple[list, list]:
        """Segment lengths and wrenches (arm ``arm_m``) as the lists the scalar RK4 loop
        reads, converted once per grid (every evaluation of a fit reuses them)."""
        got = self._lists.get(arm_m)
        if got is None:
            got = self._lists[arm_m] = (np.diff(self.events).tolist(),
                                        wrench(self.seg_thrust, arm_m).tolist())
        return got


def make_grid(cmd_t, thrust_n, t_nodes, max_step: float = DEFAULT_MAX_STEP_S) -> Grid:
    """Boundaries at every node, every command switch and at most ``max_step`` apart."""
    cmd_t = np.asarray(cmd_t, dtype=float)
    thrust_n = np.asarray(thrust_n, dtype=float)
    t_nodes = np.asarray(t_nodes, dtype=float)
    events, _, _ = zoh_segments(cmd_t, t_nodes)
    gaps = np.diff(events)
    long = np.nonzero(gaps > max_step * (1 + 1e-9))[0]
    if long.size:
        # gap i split in k equal parts: events[i] + gaps[i] * j / k, j = 1..k-1 (all gaps at once)
        k = np.ceil(gaps[long] / max_step).astype(int)
        at = np.repeat(long, k - 1)
        j = np.arange(len(at)) - np.repeat(np.cumsum(k - 1) - (k - 1), k - 1) + 1
        events = np.union1d(events, events[at] + gaps[at] * j / np.repeat(k, k - 1))
    cmd_idx = np.searchsorted(cmd_t, events[:-1], side="right") - 1
    node_pos = np.searchsorted(events, t_nodes)
    return Grid(events, segment_thrust(thrust_n, cmd_idx), node_pos, cmd_t, thrust_n)


def reference_states(s0, grid: Grid, params: Mapping[str, float]) -> np.ndarray:
    """(M, 6) reference states at every grid boundary, one RK4 step per segment
    (the fused scalar loop of :func:`model.rk4_hold_chain`)."""
    p = plant_from(params)
    dts, w = grid.chain_inputs(p.arm_m)
    out = np.empty((len(grid.events), 6))
    out[0] = np.asarray(s0, float)
    rows = rk4_hold_chain(out[0], dts, w, p)
    if rows:
        out[1:] = rows
    return out


def chain_stm(phi_seg: np.ndarray, node_pos: np.ndarray) -> np.ndarray:
    """Top 6 rows of ``Phi(t_node, t0)`` from per-segment transition matrices.

    ``Phi(t_k, t0) = Phi_k ... Phi_1``, computed as a two-level scan: prefix products
    inside blocks of about sqrt(M) segments (vectorised over blocks), a short sequential
    pass over the block totals, then one batched product per node.

    Args:
        phi_seg: (M-1, n, n) transition matrix of each segment.
        node_pos: (N,) boundary index of each node (0 = t0).

    Returns:
        (N, 6, n) rows of ``Phi(t_k, t0)`` for the six plant states (the parameter
        rows are ``[0 I]``).
    """
    m1, n, _ = phi_seg.shape
    node_pos = np.asarray(node_pos)
    if m1 == 0:
        return np.broadcast_to(np.eye(n)[:6], (len(node_pos), 6, n)).copy()
    L = max(1, int(math.sqrt(m1)))
    nb = -(-m1 // L)
    blk = np.empty((nb * L, n, n))
    blk[:m1] = phi_seg
    blk[m1:] = np.eye(n)
    blk = blk.reshape(nb, L, n, n)
    pre = np.empty_like(blk)
    pre[:, 0] = blk[:, 0]
    for j in range(1, L):
        np.matmul(blk[:, j], pre[:, j - 1], out=pre[:, j])
    start = np.empty((nb, n, n))
    start[0] = np.eye(n)
    for k in range(1, nb):
        np.matmul(pre[k - 1, L - 1], start[k - 1], out=start[k])
    out = np.empty((len(node_pos), 6, n))
    first = node_pos == 0
    out[first] = np.eye(n)[:6]
    seg = node_pos[~first] - 1  # last segment ending at the node
    out[~first] = pre[seg // L, seg % L, :6, :] @ start[seg // L]
    return out


def trajectory_stm(s0, cmd_t, thrust_n, t_nodes, params: Mapping[str, float],
                   names: Sequence[str] = ("mass", "izz"),
                   max_step: float = DEFAULT_MAX_STEP_S, grid: Grid | None = None,
                   states: np.ndarray | None = None):
    """States and transition matrices at the node times.

    Args:
        s0: (6,) state at ``t_nodes[0]``.
        cmd_t, thrust_n: (Nc,), (Nc, 4) held thrusts (N); zero before ``cmd_t[0]``.
        t_nodes: (N,) increasing times, s (pose times).
        params: model keyword parameters (mass, izz, arm, ct, cr, kb, ax, ay).
        names: parameters that form the extra columns of Phi.
        max_step: longest integration step, s.
        grid, states: a precomputed :func:`make_grid` and its reference states (optional).

    Returns:
        ``(x (N, 6), Phi (N, 6, 6+p))``: states (yaw continuous) and the top six rows
        of ``Phi(t_k, t0)``: ``[:, :, :6]`` = d x(t_k)/d x(t0), ``[:, :, 6:]`` = S_x,theta.
    """
    names = check_names(names)
    if grid is None:
        grid = make_grid(cmd_t, thrust_n, t_nodes, max_step)
    if states is None:
        states = reference_states(s0, grid, params)
    kw = {k: float(v) for k, v in params.items()}
    _, phi_seg = rk4_stm(states[:-1], grid.seg_thrust, np.diff(grid.events), kw, names, n_sub=1)
    return states[grid.node_pos], chain_stm(phi_seg, grid.node_pos)


def sensitivities(cmd_t, thrust_n, t_nodes, params: Mapping[str, float],
                  s0=None, names: Sequence[str] = ("mass", "izz"),
                  max_step: float = DEFAULT_MAX_STEP_S):
    """State and output sensitivities to the parameters (Eqs. 16-18).

    Returns:
        ``(states (N, 6), S_x (N, 6, p), S_y (N, 3, p))``.
    """
    s0 = np.zeros(6) if s0 is None else np.asarray(s0, float)
    x, phi = trajectory_stm(s0, cmd_t, thrust_n, t_nodes, params, names, max_step)
    sx = phi[:, :, 6:]
    return x, sx, sx[:, :3, :].copy()


def fisher_information(phi_nodes: np.ndarray, sigma_pos_m: float, sigma_yaw_rad: float,
                       weights: np.ndarray | None = None) -> np.ndarray:
    """``F = sum_k H_k^T R^-1 H_k`` for pose outputs; ``phi_nodes`` (N, 6, n) -> (n, n)."""
    H = phi_nodes[:, :3, :]
    w = np.array([sigma_pos_m**-2, sigma_pos_m**-2, sigma_yaw_rad**-2])
    if weights is not None:
        H = H * np.sqrt(np.asarray(weights, float))[:, None, None]
    return np.einsum("kin,i,kim->nm", H, w, H, optimize=True)


def scales_for(names: Sequence[str]) -> np.ndarray:
    """(6+p,) characteristic sizes of the augmented state."""
    return np.concatenate([STATE_SCALE, [PARAM_SCALE[n] for n in names]])


def marginal_information(fisher: np.ndarray, n_nuisance: int = 6) -> np.ndarray:
    """Schur complement ``F_tt - F_ts F_ss^-1 F_st``: the information on the last block."""
    Fss = fisher[:n_nuisance, :n_nuisance]
    Fst = fisher[:n_nuisance, n_nuisance:]
    Ftt = fisher[n_nuisance:, n_nuisance:]
    d = np.sqrt(np.maximum(np.diag(Fss), 1e-300))
    # equilibrate before solving: positions and velocities differ by orders of magnitude
    sol = np.linalg.lstsq(Fss / np.outer(d, d), Fst / d[:, None], rcond=1e-14)[0] / d[:, None]
    M = Ftt - Fst.T @ sol
    return 0.5 * (M + M.T)


def safe_inverse(A: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive semi-definite (information) matrix, after equilibration.

    Directions without information (zero diagonal, or eigenvalues below 1e-13 of the
    largest after equilibration) get an infinite variance instead of a pseudo-inverse's
    misleading finite one.
    """
    A = 0.5 * (A + A.T)
    n = len(A)
    d = np.sqrt(np.abs(np.diag(A)))
    ok = d > 0
    out = np.zeros((n, n))
    out[~ok, ~ok] = np.inf
    if not ok.any():
        return out
    dd = d[ok]
    An = A[np.ix_(ok, ok)] / np.outer(dd, dd)
    try:
        L = np.linalg.cholesky(An)
        Li = np.linalg.inv(L)
        inv = Li.T @ Li
        if not np.all(np.isfinite(inv)) or np.linalg.cond(An) > 1e13:
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(An)
        small = w < 1e-13 * max(w.max(), 1e-300)
        inv = (V[:, ~small] / w[~small]) @ V[:, ~small].T
        lost = (V[:, small] ** 2).sum(axis=1) > 1e-9
        inv[lost, lost] = np.inf
    inv = inv / np.outer(dd, dd)
    out[np.ix_(ok, ok)] = 0.5 * (inv + inv.T)
    return out


@dataclass
class CRLBResult:
    """Cramér-Rao bound of one command sequence at one parameter point.

    Attributes:
        names: estimated parameters.
        fisher: (6+p, 6+p) Fisher information of the augmented initial state.
        marginal_info: (p, p) information on the parameters, initial state marginalised.
        cov: (p, p) the bound on the parameter covariance (inverse of marginal_info).
        sigma: (p,) the bound on each parameter's standard deviation (SI units).
        logdet: log det of marginal_info (the D-optimal criterion; larger is better).
        n_poses: number of poses used.
    """

    names: tuple[str, ...]
    fisher: np.ndarray
    marginal_info: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    logdet: float
    n_poses: int
    states: np.ndarray | None = None
    sens_x: np.ndarray | None = None

    def sigma_of(self, name: str) -> float:
        return float(self.sigma[self.names.index(name)]) if name in self.names else float("nan")

    @property
    def mass_sigma_kg(self) -> float:
        return self.sigma_of("mass")

    @property
    def izz_sigma_kgm2(self) -> float:
        return self.sigma_of("izz")


def crlb_from_fisher(fisher: np.ndarray, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``(marginal_info, cov, sigma, logdet)`` of the parameters from a full Fisher matrix."""
    M = marginal_information(fisher, 6)
    cov = safe_inverse(M)
    sign, logdet = np.linalg.slogdet(M)
    if not np.all(np.isfinite(cov)):
        sign = 0.0
    return M, cov, np.sqrt(np.maximum(np.diag(cov), 0.0)), float(logdet if sign > 0 else -np.inf)


def crlb(pose_t, cmd_t, thrust_n, params: Mapping[str, float], *, s0=None,
         names: Sequence[str] = ("mass", "izz"), sigma_pos_m: float = 0.01,
         sigma_yaw_rad: float = math.radians(1.0), max_step: float = DEFAULT_MAX_STEP_S,
         keep_sensitivities: bool = False) -> CRLBResult:
    """Cramér-Rao bound on ``names`` for poses at ``pose_t`` under the held thrusts.

    Args:
        pose_t: (N,) pose times, s (the first is t0, where the initial state is taken).
        cmd_t, thrust_n: (Nc,), (Nc, 4) held thrusts, N.
        params: true (or assumed) model parameters (mass, izz, arm, ct, ...).
        s0: (6,) true initial state at ``pose_t[0]`` (default: at rest at the origin).
        names: the parameters; the initial state is always a nuisance.
        sigma_pos_m, sigma_yaw_rad: pose noise standard deviations.
        keep_sensitivities: store states and S_x,theta for plotting.
    """
    names = check_names(names)
    s0 = np.zeros(6) if s0 is None else np.asarray(s0, float)
    x, phi = trajectory_stm(s0, cmd_t, thrust_n, pose_t, params, names, max_step)
    H = output_jacobian(x, phi, names, float(params.get("cx", 0.0)), float(params.get("cy", 0.0)))
    F = fisher_information(H, sigma_pos_m, sigma_yaw_rad)
    if not np.all(np.isfinite(F)):  # the motion overflowed: LAPACK would print and fail
        raise np.linalg.LinAlgError("the predicted trajectory is not finite")
    M, cov, sig, logdet = crlb_from_fisher(F, names)
    return CRLBResult(names, F, M, cov, sig, logdet, len(np.asarray(pose_t)),
                      x if keep_sensitivities else None,
                      phi[:, :, 6:] if keep_sensitivities else None)

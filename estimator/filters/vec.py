"""The EKF of :mod:`estimator.filters.ekf` vectorised across runs (Monte Carlo).

One numpy filter carries R runs at once: states (R, 8), covariances (R, 8, 8). All runs
share one time grid and one thrust history (the Monte Carlo input); a run's dropped
frames are a ``False`` in its measurement mask, so its update is skipped at that time.
Propagation is :func:`estimator.plant.propagate.propagate_stm_batch`: the plant of
:mod:`estimator.plant.model` compiled for arrays (the right-hand side and the Jacobian entries
of each RK4 stage for all runs in one pass) and the transition matrix assembled from the
four stage Jacobians, the same RK4 as :func:`estimator.plant.propagate.rk4_stm`. The update is
the same Joseph-form, optionally underweighted update as :func:`estimator.filters.ekf.ekf_update`
(with the correction of 1/m and 1/Izz when ``param_form`` is ``inverse``), written on
batched matrices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimator.filters.config import NX, NZ, PAPER, EkfConfig
from estimator.filters.kernels import MIN_INV_RATIO, filter_plant
from estimator.plant.model import ALL_EFFECTS, PARAM_NAMES, array_function, jacobian_pattern, wrench
from estimator.plant.propagate import propagate_stm_batch, segment_thrust, zoh_segments


def inv_sym3(S: np.ndarray) -> np.ndarray:
    """Inverses of symmetric 3x3 matrices (R, 3, 3) by cofactors.

    Hand-written because numpy.linalg.inv (LAPACK per matrix) is 7x slower on R = 500:
    30 us against 210-220 us (``make bench``, row "inv_sym3 against numpy.linalg.inv")."""
    a, b, c = S[:, 0, 0], S[:, 1, 1], S[:, 2, 2]
    d, e, f = S[:, 0, 1], S[:, 0, 2], S[:, 1, 2]
    A = b * c - f * f
    B = e * f - d * c
    C = d * f - b * e
    k = 1.0 / (a * A + d * B + e * C)
    out = np.empty_like(S)
    out[:, 0, 0] = A * k
    out[:, 0, 1] = out[:, 1, 0] = B * k
    out[:, 0, 2] = out[:, 2, 0] = C * k
    out[:, 1, 1] = (a * c - e * e) * k
    out[:, 1, 2] = out[:, 2, 1] = (d * e - a * f) * k
    out[:, 2, 2] = (a * b - d * d) * k
    return out


def _known_plant(known, arm_m=None):
    fixed = dict(zip(PARAM_NAMES[2:7], known, strict=True))
    if arm_m is not None:
        fixed["arm"] = arm_m
    return filter_plant(("mass", "izz"), fixed)


def rhs_batch(s, w, m, izz, known):
    """Plant right-hand side (R, 6) for many states, shared wrench w (3,); as model.dynamics."""
    return rhs_jac_batch(s, w, m, izz, known, with_jac=False)[0]


def rhs_jac_batch(s, w, m, izz, known, with_jac: bool = True):
    """Plant right-hand side and 8-state Jacobian entries for many states.

    Args:
        s: (R, 6) states. w: (3,) body wrench (Fx, Fy, Mz) shared by all. m, izz: (R,).
        known: (ct, cr, kb, ax, ay).
    Returns:
        ``(sdot (R, 6), jac (R, 21))``: ``jac`` in the order of ``kernels._JAC_POS`` (every
        effect of :mod:`estimator.plant.model` compiled in), or None without ``with_jac``.
    """
    f = array_function(ALL_EFFECTS, ("mass", "izz") if with_jac else None)
    out = f(s[:, 2], s[:, 3], s[:, 4], s[:, 5], w[0], w[1], w[2], m, izz, *known)
    rates, vals = out if with_jac else (out, None)
    sd = np.empty((len(s), 6))
    for i, v in enumerate(rates):
        sd[:, i] = v
    if not with_jac:
        return sd, None
    jac = np.empty((len(s), len(jacobian_pattern(ALL_EFFECTS, ("mass", "izz")))))
    for q, v in enumerate(vals):
        jac[:, q] = v
    return sd, jac


def propagate_batch(x, seg_dt, seg_w, known=(0.0, 0.0, 0.0, 0.0, 0.0), max_step_s: float = 0.01):
    """Batched :func:`estimator.filters.ekf.propagate`: x (R, 8), shared segments and wrenches (3,).

    Returns ``(x_end (R, 8), Phi (R, 8, 8))``.
    """
    return propagate_stm_batch(x, seg_dt, seg_w, _known_plant(known), max_step_s)


class VecEKF:
    """Batched EKF state for R runs.

    Attributes:
        x: (R, 8) means. P: (R, 8, 8) covariances.
        nis: (R,) normalised innovation squared of the last update (NaN if skipped).
        triggered: (R,) whether the last update was underweighted.
    """

    def __init__(self, cfg: EkfConfig, x0: np.ndarray, P0: np.ndarray):
        x0 = np.asarray(x0, dtype=float)
        if x0.ndim != 2 or x0.shape[1] != NX:
            raise ValueError("x0 must be (R, 8)")
        self.cfg = cfg
        self.x = x0.copy()
        self.P = np.broadcast_to(np.asarray(P0, dtype=float), (len(x0), NX, NX)).copy()
        self.R = cfg.R
        self._q = np.asarray(cfg.q_psd, dtype=float)
        self._rw = 1.0 / np.sqrt(np.diag(self.R))
        self.nis = np.full(len(x0), np.nan)
        self.triggered = np.zeros(len(x0), bool)

    @property
    def runs(self) -> int:
        return len(self.x)

    def predict(self, seg_dt, seg_thrust_n) -> None:
        """Propagate every run over hold segments (lengths s, thrusts (4,) N each, shared by all runs)."""
        cfg = self.cfg
        seg_w = [wrench(t, cfg.arm_m) for t in seg_thrust_n]
        self.predict_w(seg_dt, seg_w)

    def predict_w(self, seg_dt, seg_w) -> None:
        """As :meth:`predict` with body wrenches (3,) per segment."""
        cfg = self.cfg
        total = float(sum(seg_dt))
        if total <= 0.0:
            return
        self.x, phi = propagate_stm_batch(self.x, seg_dt, seg_w, cfg.plant, cfg.max_step_s)
        P = phi @ self.P @ np.swapaxes(phi, -1, -2)
        for i, q in enumerate(cfg.q_psd):
            if q:
                P[:, i, i] += q * total
        self.P = P

    def update(self, meas: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Update the runs in ``mask`` with poses ``meas`` (R, 3): x m, y m, yaw rad."""
        cfg = self.cfg
        meas = np.asarray(meas, dtype=float)
        mask = np.ones(self.runs, bool) if mask is None else np.asarray(mask, bool)
        if not mask.any():
            self.nis = np.full(self.runs, np.nan)
            self.triggered = np.zeros(self.runs, bool)
            return
        P, x, R = self.P, self.x, self.R
        hph = P[:, :NZ, :NZ]
        S = hph + R
        y = meas - x[:, :NZ]
        y[:, 2] = (y[:, 2] + math.pi) % (2 * math.pi) - math.pi
        Sinv = inv_sym3(S)
        nis = np.einsum("ri,rij,rj->r", y, Sinv, y)
        trig = np.zeros(self.runs, bool)
        if cfg.underweight > 0.0:
            ratio = np.linalg.eigvalsh(hph * np.outer(self._rw, self._rw))[:, -1]
            trig = ratio > cfg.uw_trigger
            if trig.any():
                Sinv[trig] = inv_sym3((1.0 + cfg.underweight) * hph[trig] + R)
        K = P[:, :, :NZ] @ Sinv
        xn = x + np.einsum("rij,rj->ri", K, y)
        A = np.broadcast_to(np.eye(NX), P.shape).copy()
        A[:, :, :NZ] -= K
        Pn = A @ P @ np.swapaxes(A, -1, -2) + (K * np.diag(R)) @ np.swapaxes(K, -1, -2)
        if cfg._inv:
            # correct 1/m and 1/Izz (estimator.filters.ekf.inverse_correction, batched)
            for i in cfg._inv:
                old = x[:, i]
                with np.errstate(divide="ignore", invalid="ignore"):
                    ratio = 1.0 - (xn[:, i] - old) / old
                ok = old > 0.0
                ratio = np.where(ok, np.maximum(ratio, MIN_INV_RATIO), 1.0)
                xn[:, i] = np.where(ok, old / ratio, xn[:, i])
                g = 1.0 / (ratio * ratio)
                Pn[:, i, :] *= g[:, None]
                Pn[:, :, i] *= g[:, None]
        Pn = 0.5 * (Pn + np.swapaxes(Pn, -1, -2))
        self.x = np.where(mask[:, None], xn, x)
        self.P = np.where(mask[:, None, None], Pn, P)
        self.nis = np.where(mask, nis, np.nan)
        self.triggered = trig & mask


@dataclass
class VecResult:
    """Histories of a batched run: x (R, N, 8), sigma (R, N, 8), nis (R, N), triggered (R, N)."""

    t: np.ndarray
    x: np.ndarray
    sigma: np.ndarray
    nis: np.ndarray
    triggered: np.ndarray
    P: np.ndarray


def shared_schedule(t, cmd_t, thrust_n):
    """Per-interval hold segments on the common grid ``t``: lists of (lengths, thrusts (4,))."""
    events, cmd_idx, node_pos = zoh_segments(cmd_t, t)
    thr = segment_thrust(thrust_n, cmd_idx)
    dts = np.diff(events)
    seg_dt, seg_thr = [[]], [[]]
    for k in range(1, len(t)):
        a, b = int(node_pos[k - 1]), int(node_pos[k])
        seg_dt.append(dts[a:b].tolist())
        seg_thr.append(list(thr[a:b]))
    return seg_dt, seg_thr


def run_ekf_vec(t, pose, mask, cmd_t, thrust_n, cfg: EkfConfig = PAPER, x0=None, P0=None
                ) -> VecResult:
    """Filter R pose histories on a common grid at once, keeping the full histories.

    Args:
        t: (N,) common pose times, s. pose: (R, N, 3). mask: (R, N) bool, which poses exist.
        cmd_t, thrust_n: shared thrust history (Nc,), (Nc, 4) N.
        cfg: settings; x0 (R, 8) and P0 (8, 8) or (R, 8, 8) default from cfg.
    Memory grows as R x N x 8; the Monte Carlo streams instead (:mod:`estimator.montecarlo`).
    """
    pose = np.asarray(pose, dtype=float)
    r, n = pose.shape[:2]
    mask = np.ones((r, n), bool) if mask is None else np.asarray(mask, bool)
    x0 = np.tile(cfg.x0, (r, 1)) if x0 is None else x0
    P0 = cfg.P0 if P0 is None else P0
    f = VecEKF(cfg, x0, P0)
    seg_dt, seg_thr = shared_schedule(np.asarray(t, float), cmd_t, thrust_n)
    xs = np.empty((r, n, NX))
    sig = np.empty((r, n, NX))
    nis = np.full((r, n), np.nan)
    trig = np.zeros((r, n), bool)
    for k in range(n):
        if k:
            f.predict(seg_dt[k], seg_thr[k])
        if mask[:, k].any():
            f.update(pose[:, k], mask[:, k])
            nis[:, k] = f.nis
            trig[:, k] = f.triggered
        xs[:, k] = f.x
        sig[:, k] = np.sqrt(np.diagonal(f.P, axis1=1, axis2=2))
    return VecResult(np.asarray(t, float), xs, sig, nis, trig, f.P)


__all__ = ["VecEKF", "VecResult", "propagate_batch", "run_ekf_vec", "shared_schedule"]

"""The EKF of :mod:`estimator.ekf` vectorised across runs (Monte Carlo).

One numpy filter carries R runs at once: states (R, 8), covariances (R, 8, 8). All runs
share one time grid and one thrust history (the Monte Carlo input); a run's dropped
frames are a ``False`` in its measurement mask, so its update is skipped at that time.
Propagation is :func:`estimator.propagate.rk4_stm` with leading dimension R; the
update is the same Joseph-form, optionally underweighted update as
:func:`estimator.ekf.ekf_update`, written on batched matrices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimator.ekf import NX, NZ, PAPER, EkfConfig, make_schedule
from estimator.propagate import rk4_stm, segment_thrust, zoh_segments

_NAMES = ("mass", "izz")


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
        params = {"mass": self.x[:, 6], "izz": self.x[:, 7], "arm": cfg.arm_m, "ct": cfg.ct,
                  "cr": cfg.cr, "kb": cfg.kb, "ax": cfg.ax, "ay": cfg.ay}
        s = self.x[:, :6]
        phi = None
        total = 0.0
        for dt, thr in zip(seg_dt, seg_thrust_n, strict=True):
            if dt <= 0.0:
                continue
            n_sub = max(1, math.ceil(dt / cfg.max_step_s - 1e-9))
            s, p = rk4_stm(s, thr, dt, params, _NAMES, n_sub)
            phi = p if phi is None else p @ phi
            total += dt
        if phi is None:
            return
        x = self.x.copy()
        x[:, :6] = s
        self.x = x
        P = phi @ self.P @ np.swapaxes(phi, -1, -2)
        if total > 0:
            idx = np.arange(NX)
            P[:, idx, idx] += self._q * total
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
        Sinv = np.linalg.inv(S)
        nis = np.einsum("ri,rij,rj->r", y, Sinv, y)
        trig = np.zeros(self.runs, bool)
        if cfg.underweight > 0.0:
            ratio = np.linalg.eigvalsh(hph * np.outer(self._rw, self._rw))[:, -1]
            trig = ratio > cfg.uw_trigger
            if trig.any():
                Su = (1.0 + cfg.underweight) * hph[trig] + R
                Sinv[trig] = np.linalg.inv(Su)
        K = P[:, :, :NZ] @ Sinv
        xn = x + np.einsum("rij,rj->ri", K, y)
        A = np.broadcast_to(np.eye(NX), P.shape).copy()
        A[:, :, :NZ] -= K
        Pn = A @ P @ np.swapaxes(A, -1, -2) + (K * np.diag(R)) @ np.swapaxes(K, -1, -2)
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


__all__ = ["VecEKF", "VecResult", "run_ekf_vec", "shared_schedule", "make_schedule"]

"""filterpy's ``ExtendedKalmanFilter`` as the TPODS filter: the public, tested adapter.

:class:`TpodsEKF` runs the same propagation as the lean filter of
:mod:`estimator.filters.ekf` (``predict_x`` integrates the model and sets ``F`` to the
analytic transition matrix) and filterpy's Joseph-form update with an angle-wrapping
residual; :func:`run_filterpy` runs it over a whole run. The tests use it as the
reference for the lean filter and the vectorised one.

It imports the filter's modules (:mod:`estimator.filters.config`, ``kernels``,
``loop``, ``result``), never :mod:`estimator.filters.ekf`, which loads this module
on first use of ``TpodsEKF`` or ``run_filterpy`` (no import cycle).
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from estimator.filters.config import NX, NZ, PAPER, EkfConfig
from estimator.filters.kernels import inverse_correction, uw_ratio, wrap_residual
from estimator.filters.loop import initial_estimate, make_schedule
from estimator.filters.result import EkfResult
from estimator.plant.propagate import propagate_stm


def _hjac(_x):
    H = np.zeros((NZ, NX))
    H[0, 0] = H[1, 1] = H[2, 2] = 1.0
    return H


def _hx(x):
    return x[:NZ].copy()


class TpodsEKF(ExtendedKalmanFilter):
    """filterpy ``ExtendedKalmanFilter`` for the augmented TPODS state.

    ``predict(u=(seg_dt, seg_w))`` propagates through the hold segments of one pose
    interval: the overridden ``predict_x`` integrates the nonlinear model, sets
    ``F`` to the analytic transition matrix and ``Q`` to ``diag(q_psd) * dt``, then
    filterpy forms ``F P F^T + Q``. :meth:`update_pose` takes a pose (3,), passes it
    as a column vector with an angle-wrapping residual (Joseph-form update by
    filterpy), or runs the underweighted update while it is triggered.
    """

    def __init__(self, cfg: EkfConfig = PAPER, x0=None, P0=None):
        super().__init__(dim_x=NX, dim_z=NZ)
        x, P = initial_estimate(cfg, x0, P0)
        self.cfg = cfg
        self.x = x.reshape(NX, 1)
        self.P = P.copy()
        self.R = cfg.R
        self.triggered = False

    def predict_x(self, u=0):
        seg_dt, seg_w = u
        z, phi = propagate_stm(self.x.ravel(), seg_dt, seg_w, self.cfg.plant, self.cfg.max_step_s)
        self.x = z.reshape(NX, 1)
        self.F = phi
        self.Q = np.diag(np.asarray(self.cfg.q_psd) * float(sum(seg_dt)))

    def update_pose(self, pose) -> None:
        """Pose update; with ``cfg.param_form == "inverse"`` the correction of m and Izz is
        made on 1/m and 1/Izz (:func:`estimator.filters.kernels.inverse_correction`)."""
        prior = self.x.ravel().copy()
        self._update_pose(pose)
        if self.cfg._inv:
            x = self.x.ravel().copy()
            P = np.array(self.P, dtype=float)
            inverse_correction(prior, x, P, self.cfg._inv)
            self.x = x.reshape(NX, 1)
            self.P = P

    def _update_pose(self, pose) -> None:
        zc = np.asarray(pose, dtype=float).reshape(NZ, 1)
        cfg = self.cfg
        self.triggered = cfg.underweight > 0.0 and uw_ratio(self.P, self.R) > cfg.uw_trigger
        if not self.triggered:
            self.update(zc, _hjac, _hx, R=self.R, residual=wrap_residual)
        else:
            H = _hjac(self.x)
            PHT = self.P @ H.T
            self.S = (1.0 + cfg.underweight) * (H @ PHT) + self.R
            self.SI = np.linalg.inv(self.S)
            self.K = PHT @ self.SI
            self.y = wrap_residual(zc, _hx(self.x))
            self.x = self.x + self.K @ self.y
            I_KH = self._I - self.K @ H
            self.P = I_KH @ self.P @ I_KH.T + self.K @ self.R @ self.K.T


def run_filterpy(pose_t, pose, cmd_t, thrust_n, cfg: EkfConfig = PAPER, x0=None, P0=None,
                 use=None) -> EkfResult:
    """Same as :func:`run_ekf` with :class:`TpodsEKF` (slower; the reference implementation)."""
    pose = np.asarray(pose, dtype=float)
    sched = make_schedule(pose_t, cmd_t, thrust_n, cfg.arm_m)
    n = len(sched.pose_t)
    use = np.ones(n, bool) if use is None else np.asarray(use, bool)
    f = TpodsEKF(cfg, x0, P0)
    xs = np.empty((n, NX))
    sig = np.empty((n, NX))
    nis = np.full(n, np.nan)
    trig = np.zeros(n, bool)
    for k in range(n):
        if k:
            f.predict(u=(sched.seg_dt[k], sched.seg_w[k]))
        if use[k]:
            Sp = f.P[:NZ, :NZ] + f.R
            y = wrap_residual(pose[k], f.x.ravel()[:NZ])
            nis[k] = float(y @ np.linalg.solve(Sp, y))
            f.update_pose(pose[k])
            trig[k] = f.triggered
        xs[k] = f.x.ravel()
        sig[k] = np.sqrt(np.diag(f.P))
    return EkfResult(sched.pose_t.copy(), xs, sig, f.P.copy(), use.copy(), trig, nis)

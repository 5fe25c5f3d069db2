"""The filter loop over a pose history: hold segments, the start, :func:`run_filter`.

:func:`make_schedule` splits the pose intervals at the command switches (the zero-order-hold
segments each prediction integrates over); :func:`run_filter` is the EKF loop for any
parameter set (the 8-state filter through :func:`run_ekf`, the extended filter of
:mod:`estimator.filters.ext` too), predicting and updating pose by pose with the
kernels of :mod:`estimator.filters.kernels`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.filters.config import NX, PAPER, EkfConfig
from estimator.filters.kernels import _offset_spec, _predict, _update, _update_offset
from estimator.filters.result import EkfResult
from estimator.plant.model import ARM_M, wrench
from estimator.plant.propagate import AugmentedPlant, segment_thrust, zoh_segments


@dataclass
class Schedule:
    """Hold segments between consecutive pose times.

    ``seg_dt[k]`` and ``seg_w[k]`` list the segments from ``pose_t[k-1]`` to
    ``pose_t[k]`` (empty for k = 0).
    """

    pose_t: np.ndarray
    seg_dt: list[list[float]]
    seg_w: list[list[tuple[float, float, float]]]


def make_schedule(pose_t, cmd_t, thrust_n, arm_m: float = ARM_M) -> Schedule:
    """Split the pose intervals at command switches (thrust zero before the first command)."""
    pose_t = np.asarray(pose_t, dtype=float)
    events, cmd_idx, node_pos = zoh_segments(cmd_t, pose_t)
    w = wrench(segment_thrust(thrust_n, cmd_idx), arm_m).tolist()
    dts = np.diff(events).tolist()
    seg_dt: list[list[float]] = [[]]
    seg_w: list[list] = [[]]
    for k in range(1, len(pose_t)):
        a, b = int(node_pos[k - 1]), int(node_pos[k])
        seg_dt.append(dts[a:b])
        seg_w.append(w[a:b])
    return Schedule(pose_t, seg_dt, seg_w)


def initial_estimate(cfg: EkfConfig, x0, P0):
    """The filter's start ``(x (8,), P (8, 8))``: the given values or the setting's."""
    x = np.array(cfg.x0 if x0 is None else x0, dtype=float)
    P = cfg.P0 if P0 is None else np.array(P0, dtype=float)
    if x.shape != (NX,) or P.shape != (NX, NX):
        raise ValueError("x0 must be (8,) and P0 (8, 8)")
    return x, P


def run_ekf(pose_t, pose, cmd_t, thrust_n, cfg: EkfConfig = PAPER, x0=None, P0=None,
            use=None, keep_cov: bool = False, progress=None) -> EkfResult:
    """Filter a pose history with the lean EKF.

    Args:
        pose_t: (N,) increasing pose times, s (any spacing; dropped frames are gaps).
        pose: (N, 3) x (m), y (m), yaw (rad, wrapped or not).
        cmd_t, thrust_n: (Nc,), (Nc, 4) zero-order-hold thrusts, N.
        cfg: filter settings. x0, P0: initial mean (8,) and covariance (8, 8) at
            ``pose_t[0]`` (default from cfg).
        use: optional (N,) bool, which poses to update with (others: predict only).
        keep_cov: also return every covariance.
        progress: optional callable(k) called every 1000 poses.
    """
    sched = make_schedule(pose_t, cmd_t, thrust_n, cfg.arm_m)
    x, P = initial_estimate(cfg, x0, P0)
    return run_filter(sched, pose, cfg.plant, x, P, cfg.R, cfg._q_nz, cfg.max_step_s,
                      cfg.underweight, cfg.uw_trigger, use, keep_cov, progress, inv=cfg._inv)


def run_filter(sched: Schedule, pose, plant: AugmentedPlant, x, P, R, q_nz=(),
               max_step_s: float = 0.01, underweight: float = 0.0, uw_trigger: float = 1.0,
               use=None, keep_cov: bool = False, progress=None, *, q_per_step: bool = False,
               stop_on_blowup: bool = False, inv=()) -> EkfResult:
    """The EKF loop for any model (the one filter behind :func:`run_ekf` and the extended
    filter of :mod:`estimator.filters.ext`).

    Args:
        sched: hold segments between the poses (:func:`make_schedule`).
        pose: (N, 3) x, y (m), yaw (rad). plant: the model (:class:`AugmentedPlant`).
        x, P: (n,), (n, n) initial mean and covariance at the first pose.
        R: (3, 3) diagonal pose covariance. q_nz: non-zero process-noise densities as
            ``(state index, units^2/s)``. max_step_s: longest RK4 step.
        underweight, uw_trigger: the underweighted update (alpha 0 = off).
        use: optional (N,) bool, poses to update with (others: predict only).
        keep_cov: keep every covariance. progress: callable(k) every 1000 poses.
        q_per_step: add the process noise after every RK4 step (else once per interval).
        stop_on_blowup: a prediction that overflows ends the filter: NaN from there on.
        inv: state indices of mass and Izz to correct as 1/m and 1/Izz
            (:func:`inverse_correction`); empty: corrected directly.
    """
    pose = np.asarray(pose, dtype=float)
    n = len(sched.pose_t)
    nx = plant.n
    use = np.ones(n, bool) if use is None else np.asarray(use, bool)
    xs = np.empty((n, nx))
    sig = np.empty((n, nx))
    nis = np.full(n, np.nan)
    trig = np.zeros(n, bool)
    covs = np.empty((n, nx, nx)) if keep_cov else None
    meas = pose.tolist()
    off = _offset_spec(plant)
    if off is not None and underweight > 0:
        raise ValueError("underweighting is not built for a tracked frame off the centre of mass")
    for k in range(n):
        if k:
            if stop_on_blowup:
                with np.errstate(over="ignore", invalid="ignore"):
                    try:
                        x, P, _ = _predict(x, P, sched.seg_dt[k], sched.seg_w[k], plant, q_nz,
                                           max_step_s, q_per_step)
                    except (ValueError, OverflowError):  # the scalar stage's math.cos(inf)
                        x = np.full(nx, np.nan)
                if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
                    xs[k:] = np.nan
                    sig[k:] = np.nan
                    P = np.full((nx, nx), np.nan)
                    if keep_cov:
                        covs[k:] = np.nan
                    break
            else:
                x, P, _ = _predict(x, P, sched.seg_dt[k], sched.seg_w[k], plant, q_nz,
                                   max_step_s, q_per_step)
        if use[k]:
            if off is None:
                x, P, (nis[k], trig[k]) = _update(x, P, meas[k], R, underweight, uw_trigger,
                                                  (k & 15) == 0, inv)
            else:
                x, P, (nis[k], trig[k]) = _update_offset(x, P, meas[k], R, off, inv)
        xs[k] = x
        sig[k] = P.diagonal()
        if keep_cov:
            covs[k] = P
        if progress is not None and k % 1000 == 0:
            progress(k)
    np.sqrt(np.maximum(sig, 0.0), out=sig)
    return EkfResult(sched.pose_t.copy(), xs, sig, P, use.copy(), trig, nis, covs)

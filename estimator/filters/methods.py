"""The filter methods on a whole run: ``ekf`` and ``ls-ekf`` (:func:`estimate_filter`).

``ekf`` filters the run from the setting's (or the given) start; ``ls-ekf`` starts the
filter from batch least squares on the first ``ls_window_s`` seconds (``reuse``: the
paper, the window's poses used again; ``handoff``: each pose used once).
:class:`FilterEstimate` holds the filter run, the batch fit and the plausibility of the
result (:mod:`estimator.filters.plausibility`) and its JSON (``to_dict``);
:func:`initial_rates` gives a start for a run that does not begin at rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from estimator.filters.config import NX, PAPER, STATE_NAMES, EkfConfig
from estimator.filters.loop import Schedule, initial_estimate, make_schedule, run_ekf
from estimator.filters.plausibility import filter_plausibility
from estimator.filters.result import EkfResult

FILTER_METHODS = ("ekf", "ls-ekf")
LS_STARTS = ("reuse", "handoff")


@dataclass
class FilterEstimate:
    """Result of :func:`estimate_filter`: the filter run and, for ls-ekf, the batch fit."""

    method: str
    result: EkfResult
    ls: object | None = None
    ls_window_s: float | None = None
    ls_start: str | None = None
    no_information: str = ""
    """'' or which parameter learnt nothing from the run, and why (:func:`filter_plausibility`)."""
    warnings: list[str] = field(default_factory=list)
    """Post-update residuals far from the stated noise (:func:`filter_plausibility`)."""
    rms_residuals: np.ndarray | None = None

    @property
    def converged(self) -> bool:
        """Not diverged, and every parameter learnt from the run."""
        return not self.result.diverged and not self.no_information

    def to_dict(self) -> dict:
        r = self.result
        P = r.P
        # a diverged filter can end with a negative variance: no sigma then (NaN), and
        # ``diverged`` is True
        sm, si = (math.sqrt(v) if v > 0 and math.isfinite(v) else math.nan
                  for v in (float(P[6, 6]), float(P[7, 7])))
        d = {
            "method": self.method,
            "mass_kg": r.mass_kg, "mass_sigma_kg": sm,
            "izz_kgm2": r.izz_kgm2, "izz_sigma_kgm2": si,
            "corr_mass_izz": float(P[6, 7] / (sm * si)) if sm > 0 and si > 0 else None,
            "final_state": dict(zip(STATE_NAMES, r.x[-1].tolist(), strict=True)),
            "final_sigma": dict(zip(STATE_NAMES, r.sigma[-1].tolist(), strict=True)),
            "t0_s": float(r.t[0]), "t1_s": float(r.t[-1]), "n_poses": int(len(r.t)),
            "n_updates": int(r.updated.sum()),
            "nis_mean": float(np.nanmean(r.nis)) if r.updated.any() else None,
            "underweighted_updates": int(r.triggered.sum()),
            "diverged": r.diverged,
            "nis_tail_mean": r.nis_tail_mean if r.updated.any() else None,
            "inconsistent": r.inconsistent,
            "nis_block_excess": r.nis_block_excess if r.updated.any() else None,
            "converged": self.converged,
        }
        if self.no_information:
            d["message"] = "not converged: " + self.no_information
        if self.rms_residuals is not None:
            rx, ry, rw = (float(v) for v in self.rms_residuals)
            d.update({"rms_residual_x_m": rx, "rms_residual_y_m": ry, "rms_residual_yaw_rad": rw})
        if self.warnings:
            d["warnings"] = list(self.warnings)
        if self.ls is not None:
            d["ls_window_s"] = self.ls_window_s
            d["ls_start"] = self.ls_start
            d["ls"] = {"mass_kg": self.ls.mass_kg, "mass_sigma_kg": self.ls.mass_sigma_kg,
                       "izz_kgm2": self.ls.izz_kgm2, "izz_sigma_kgm2": self.ls.izz_sigma_kgm2,
                       "converged": self.ls.converged, "message": self.ls.message,
                       "n_poses": int(len(self.ls.t))}
        return d


def estimate_filter(pose_t, pose, cmd_t, thrust_n, method: str = "ekf", cfg: EkfConfig = PAPER,
                    x0=None, P0=None, ls_window_s: float = 20.0, ls_start: str = "reuse",
                    ls_kwargs: dict | None = None) -> FilterEstimate:
    """Run ``ekf`` or ``ls-ekf`` on one pose history.

    ``ls-ekf``: batch least squares (:func:`estimator.batch.least_squares.batch_ls`) on the poses of
    the first ``ls_window_s`` seconds gives the mean and full covariance at
    ``pose_t[0]``. ``ls_start="reuse"`` (the paper) then filters the whole run from
    there, so the window's poses are used twice (by the fit and by the filter) and the
    filter is over-confident; ``"handoff"`` propagates the fit through the window
    without updates and filters only the later poses, each pose used once.
    Raises ValueError for a bad method and UserError when the batch fit fails.
    """
    from common.errors import UserError

    if method not in FILTER_METHODS:
        raise ValueError(f"method must be one of {', '.join(FILTER_METHODS)}")
    if method == "ekf":
        x, P = initial_estimate(cfg, x0, P0)
        sched = make_schedule(pose_t, cmd_t, thrust_n, cfg.arm_m)
        # a filter that blows up (poses in mm, yaw in degrees) overflows: flagged diverged
        # and explained by the plausibility check, not numpy warnings on the terminal
        with np.errstate(over="ignore", invalid="ignore"):
            res = run_ekf(pose_t, pose, cmd_t, thrust_n, cfg, x, P)
        return _checked(FilterEstimate(method, res), pose, cfg, np.sqrt(np.diag(P)), sched)
    if ls_start not in LS_STARTS:
        raise ValueError(f"ls_start must be one of {', '.join(LS_STARTS)}")
    from estimator.batch.least_squares import batch_ls

    pose_t = np.asarray(pose_t, dtype=float)
    pose = np.asarray(pose, dtype=float)
    win = pose_t <= pose_t[0] + ls_window_s
    if win.sum() < 4:
        raise UserError(f"the LS window of {ls_window_s:g} s holds fewer than 4 poses")
    kw = {"sigma_pos_m": cfg.sigma_meas[0], "sigma_yaw_rad": cfg.sigma_meas[2],
          "fixed": cfg.known_params}
    kw.update(ls_kwargs or {})
    ls = batch_ls(pose_t[win], pose[win], cmd_t, thrust_n, **kw)
    if not ls.converged:
        raise UserError(f"batch least squares on the first {ls_window_s:g} s did not converge "
                        f"({ls.message}); cannot start ls-ekf from it")
    if ls.z0[6] <= 0 or ls.z0[7] <= 0:
        raise UserError("batch least squares gave a non-physical start (mass or Izz <= 0)")
    if not np.all(np.isfinite(ls.cov)):
        # e.g. a window without any torque: Izz has no information, an infinite variance
        unknown = [lab for lab, sd in zip(ls.labels, ls.sigma, strict=True) if not math.isfinite(sd)]
        raise UserError(f"the first {ls_window_s:g} s do not determine {', '.join(unknown)} "
                        "(no information: infinite variance); lengthen --ls-window or use "
                        "--method ls")
    cov = 0.5 * (ls.cov + ls.cov.T)
    use = None if ls_start == "reuse" else ~win
    with np.errstate(over="ignore", invalid="ignore"):  # flagged, as above
        res = run_ekf(pose_t, pose, cmd_t, thrust_n, cfg, ls.z0, cov, use=use)
    # the information check of the filter is against the prior sigma (the LS start has
    # already refused a window without information)
    return _checked(FilterEstimate(method, res, ls, ls_window_s, ls_start), pose, cfg,
                    np.full(NX, math.inf), make_schedule(pose_t, cmd_t, thrust_n, cfg.arm_m))


def _checked(fe: FilterEstimate, pose, cfg: EkfConfig, sigma0, sched: Schedule
             ) -> FilterEstimate:
    """``fe`` with its plausibility (:func:`filter_plausibility`) filled in."""
    r = fe.result
    fe.no_information, fe.warnings, fe.rms_residuals = filter_plausibility(
        r.t, r.x, r.sigma, r.updated, pose, cfg.sigma_meas, sigma0, sched.seg_w)
    return fe


def initial_rates(pose_t, pose, span_s: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame velocities (u, v, r) at ``pose_t[0]`` from a straight-line fit of the poses.

    Fits x, y and the unwrapped yaw linearly over the first ``span_s`` seconds (at least 3
    poses). Returns ``(rates (3,), sigmas (3,))``: the fitted u, v (m/s) and r (rad/s), and
    the standard deviations of the fitted slopes from the fit residuals. Use it to start a
    filter on a run (or a window) that does not begin at rest.
    """
    t = np.asarray(pose_t, dtype=float)
    p = np.asarray(pose, dtype=float)
    n = max(3, int(np.searchsorted(t, t[0] + span_s, side="right")))
    n = min(n, len(t))
    if n < 3:
        return np.zeros(3), np.full(3, np.inf)
    tt = t[:n] - t[0]
    yaw = np.unwrap(p[:n, 2])
    X = np.column_stack([np.ones(n), tt])
    Y = np.column_stack([p[:n, 0], p[:n, 1], yaw])
    coef, *_ = np.linalg.lstsq(X, Y, rcond=None)
    res = Y - X @ coef
    dof = max(n - 2, 1)
    s2 = np.sum(res**2, axis=0) / dof
    var_slope = s2 * np.linalg.inv(X.T @ X)[1, 1]
    xd, yd, r = coef[1]
    c, s = math.cos(coef[0, 2]), math.sin(coef[0, 2])
    u = xd * c + yd * s
    v = -xd * s + yd * c
    sig_uv = math.sqrt(max(var_slope[0], var_slope[1]))
    return np.array([u, v, r]), np.array([sig_uv, sig_uv, math.sqrt(var_slope[2])])


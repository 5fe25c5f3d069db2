"""Extended-state EKF: pose, velocities and any subset of the plant parameters.

The state is ``z = (x, y, psi, u, v, r, theta)`` with ``theta`` the parameters in
``names`` (any subset of ``model.PARAM_NAMES`` holding mass and izz, e.g. the
``friction`` model's mass, izz, ct, cr, kb); the others are fixed. It is the filter of
:mod:`estimator.filters.ekf` (:func:`estimator.filters.loop.run_filter`) with the parameter set as a model
setting; this module holds its settings, defaults and result:

- prediction over the zero-order-hold segments between poses (split at every command
  switch and at most ``max_step_s`` apart), RK4 with the analytic Jacobians of
  :mod:`estimator.plant.model`; ``P <- Phi P Phi^T + diag(q) dt`` after every RK4 step;
- update with the pose ``(x, y, psi)``, ``H = [I3 0]``, yaw innovation wrapped (the state
  yaw stays continuous), Joseph form;
- a prediction that overflows ends the filter (NaN from there on, ``diverged``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimator.filters.config import PARAM_FORMS
from estimator.filters.kernels import _update, filter_plant
from estimator.filters.loop import make_schedule, run_filter
from estimator.plant.model import ARM_M, PARAM_NAMES, STATE_NAMES

SIGMA0 = {"x": 0.1, "y": 0.1, "psi": math.radians(5.0), "u": 0.1, "v": 0.1,
          "r": math.radians(2.0), "mass": 1.0, "izz": 2e-3, "ct": 0.3, "cr": 2e-3,
          "kb": 1e-2, "ax": 1e-2, "ay": 1e-2, "cx": 0.1, "cy": 0.1}
"""Default initial standard deviations (the paper's for the 8 states; friction and tilt
wide enough to cover an air table with ball transfers and a 1 mrad tilt)."""

X0 = {"mass": 1.0, "izz": 5e-3, "ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0, "ay": 0.0,
      "cx": 0.0, "cy": 0.0}
"""Default initial parameter means (the paper's m = 1 kg, Izz = 5e-3 kg m^2; no friction, level)."""


@dataclass(frozen=True)
class ExtEkfConfig:
    """Settings of the extended filter (SI units).

    Attributes:
        names: estimated parameters (must include mass and izz).
        fixed: values of the other model parameters (arm, ct, cr, kb, ax, ay; default 0.05 m / 0).
        sigma_meas: (3,) pose noise standard deviations (m, m, rad).
        q_psd: process-noise spectral density per state or parameter name, units^2/s
            (default none: the parameters are constants).
        max_step_s: longest propagation step, s.
        param_form: ``"inverse"`` (default): the update corrects 1/m and 1/Izz, as the
            8-state filter does (:func:`estimator.filters.kernels.inverse_correction`);
            ``"direct"``: m and Izz.
    """

    names: tuple[str, ...] = ("mass", "izz", "ct", "cr", "kb")
    fixed: Mapping[str, float] = field(default_factory=dict)
    sigma_meas: tuple[float, float, float] = (0.01, 0.01, math.radians(1.0))
    q_psd: Mapping[str, float] = field(default_factory=dict)
    max_step_s: float = 0.01
    param_form: str = "inverse"

    def __post_init__(self):
        if self.param_form not in PARAM_FORMS:
            raise ValueError(f"param_form must be one of {', '.join(PARAM_FORMS)}")
        bad = [n for n in self.names if n not in PARAM_NAMES]
        if bad or len(set(self.names)) != len(self.names):
            raise ValueError(f"names must be distinct parameters from {PARAM_NAMES}")
        if not {"mass", "izz"} <= set(self.names):
            raise ValueError("the extended filter estimates mass and izz plus extras")
        if any(s <= 0 for s in self.sigma_meas):
            raise ValueError("measurement sigmas must be positive")
        unknown = set(self.q_psd) - set(self.labels)
        if unknown or any(q < 0 for q in self.q_psd.values()):
            raise ValueError(f"q_psd: non-negative values for {self.labels}")

    @property
    def labels(self) -> tuple[str, ...]:
        return STATE_NAMES + tuple(self.names)

    @property
    def R(self) -> np.ndarray:
        return np.diag(np.square(self.sigma_meas))

    def base_params(self) -> dict[str, float]:
        d = {"arm": ARM_M, "ct": 0.0, "cr": 0.0, "kb": 0.0, "ax": 0.0, "ay": 0.0, "cx": 0.0,
             "cy": 0.0}
        d.update({k: float(v) for k, v in self.fixed.items()})
        return d

    def default_x0(self, first_pose=None) -> np.ndarray:
        """Initial mean: the centre of mass at the first pose moved by the offset's guess
        (the states are the centre of mass's), at rest; parameters at X0 (or fixed)."""
        from estimator.plant.output import com_from_tracked

        z = np.zeros(6 + len(self.names))
        z[6:] = [X0[n] for n in self.names]
        if first_pose is not None:
            b = self.base_params()
            cx = z[6 + self.names.index("cx")] if "cx" in self.names else b["cx"]
            cy = z[6 + self.names.index("cy")] if "cy" in self.names else b["cy"]
            z[:3] = com_from_tracked(np.asarray(first_pose, float), cx, cy)
        return z

    def default_P0(self) -> np.ndarray:
        return np.diag(np.square([SIGMA0[n] for n in self.labels]))


@dataclass
class ExtEkfResult:
    """Filter history (SI units).

    Attributes:
        names: parameter names; t: (N,) pose times; x: (N, 6+p) posterior means;
        sigma: (N, 6+p) their standard deviations; P: final covariance;
        updated: (N,) pose used; nis: (N,) normalised innovation squared (NaN if not used).
    """

    names: tuple[str, ...]
    t: np.ndarray
    x: np.ndarray
    sigma: np.ndarray
    P: np.ndarray
    updated: np.ndarray
    nis: np.ndarray

    @property
    def labels(self) -> tuple[str, ...]:
        return STATE_NAMES + self.names

    def final(self, name: str) -> tuple[float, float]:
        i = self.labels.index(name)
        return float(self.x[-1, i]), float(self.sigma[-1, i])

    @property
    def mass_kg(self) -> float:
        return self.final("mass")[0]

    @property
    def izz_kgm2(self) -> float:
        return self.final("izz")[0]

    def rmse(self, mass_kg: float, izz_kgm2: float) -> tuple[float, float]:
        """RMS error of m and Izz over every pose time, kg and kg m^2."""
        im, ii = self.labels.index("mass"), self.labels.index("izz")
        return (float(np.sqrt(np.mean((self.x[:, im] - mass_kg) ** 2))),
                float(np.sqrt(np.mean((self.x[:, ii] - izz_kgm2) ** 2))))

    @property
    def diverged(self) -> bool:
        m, i = self.mass_kg, self.izz_kgm2
        if not (m > 0 and i > 0 and np.all(np.isfinite(self.x[-1]))):
            return True
        im, ii = self.labels.index("mass"), self.labels.index("izz")
        if not (self.P[im, im] > 0 and self.P[ii, ii] > 0 and np.all(np.isfinite(self.P))):
            return True  # the covariance broke down (a negative variance)
        nis = self.nis[self.updated]
        tail = nis[-max(1, len(nis) // 10):] if len(nis) else nis
        return bool(len(tail) and np.nanmean(tail) > 10.0)

    def to_dict(self) -> dict[str, Any]:
        P = self.P
        sd = np.sqrt(np.maximum(np.diag(P), 0))
        im, ii = self.labels.index("mass"), self.labels.index("izz")
        corr = P / np.outer(np.where(sd > 0, sd, 1), np.where(sd > 0, sd, 1))
        return {"mass_kg": self.mass_kg, "mass_sigma_kg": float(sd[im]),
                "izz_kgm2": self.izz_kgm2, "izz_sigma_kgm2": float(sd[ii]),
                "corr_mass_izz": float(corr[im, ii]), "estimated": list(self.names),
                "params": {n: float(self.x[-1, 6 + j]) for j, n in enumerate(self.names)},
                "sigmas": {n: float(sd[6 + j]) for j, n in enumerate(self.names)},
                "final_state": dict(zip(self.labels, self.x[-1].tolist(), strict=True)),
                "correlation": corr.tolist(), "n_poses": int(len(self.t)),
                "n_updates": int(self.updated.sum()),
                "nis_mean": float(np.nanmean(self.nis)) if self.updated.any() else None,
                "diverged": self.diverged}


def joseph_update(z: np.ndarray, P: np.ndarray, meas, R: np.ndarray):
    """Pose update of an (n,) state with ``H = [I3 0]``; returns ``(z, P, nis)``."""
    z, P, (nis, _) = _update(np.asarray(z, float), np.asarray(P, float), meas, R, 0.0, 1.0, True)
    return z, P, float(nis)


def run_ext_ekf(pose_t, pose, cmd_t, thrust_n, cfg: ExtEkfConfig, x0=None, P0=None,
                use=None, progress=None) -> ExtEkfResult:
    """Filter a pose history with the extended-state EKF.

    Args:
        pose_t: (N,) increasing pose times, s. pose: (N, 3) x, y (m), yaw (rad).
        cmd_t, thrust_n: (Nc,), (Nc, 4) zero-order-hold thrusts, N (zero before cmd_t[0]).
        cfg: settings. x0: (6+p,) initial mean (default: first pose, at rest, X0);
        P0: (6+p, 6+p) initial covariance (default SIGMA0).
        use: optional (N,) bool, poses to update with (others: predict only).
        progress: optional callable(k) every 1000 poses.
    """
    pose_t = np.asarray(pose_t, float)
    pose = np.asarray(pose, float)
    names = tuple(cfg.names)
    n = 6 + len(names)
    z = cfg.default_x0(pose[0]) if x0 is None else np.array(x0, float)
    P = cfg.default_P0() if P0 is None else np.array(P0, float)
    if z.shape != (n,) or P.shape != (n, n):
        raise ValueError(f"x0 must be ({n},) and P0 ({n}, {n})")
    base = cfg.base_params()
    plant = filter_plant(names, base)
    sched = make_schedule(pose_t, cmd_t, thrust_n, base["arm"])
    q_nz = tuple((i, float(cfg.q_psd[lab])) for i, lab in enumerate(cfg.labels)
                 if cfg.q_psd.get(lab, 0.0))
    inv = ((6 + names.index("mass"), 6 + names.index("izz")) if cfg.param_form == "inverse"
           else ())
    h = run_filter(sched, pose, plant, z, P, cfg.R, q_nz, cfg.max_step_s, use=use,
                   progress=progress, q_per_step=True, stop_on_blowup=True, inv=inv)
    return ExtEkfResult(names, pose_t.copy(), h.x, h.sigma, h.P, h.updated, h.nis)


def estimate_ext(pose_t, pose, cmd_t, thrust_n, cfg: ExtEkfConfig, method: str = "ekf",
                 x0=None, P0=None, ls_window_s: float = 20.0, ls_start: str = "reuse",
                 ls_kwargs: Mapping[str, Any] | None = None):
    """``ekf`` or ``ls-ekf`` with the extended state (same semantics as
    :func:`estimator.filters.ekf.estimate_filter`). Returns ``(ExtEkfResult, BatchResult or None)``.
    """
    from common.errors import UserError
    from estimator.batch.least_squares import batch_ls

    if method == "ekf":
        return run_ext_ekf(pose_t, pose, cmd_t, thrust_n, cfg, x0, P0), None
    if method != "ls-ekf":
        raise ValueError("method must be ekf or ls-ekf")
    pose_t = np.asarray(pose_t, float)
    pose = np.asarray(pose, float)
    win = pose_t <= pose_t[0] + ls_window_s
    kw = {"names": cfg.names, "fixed": dict(cfg.fixed), "sigma_pos_m": cfg.sigma_meas[0],
          "sigma_yaw_rad": cfg.sigma_meas[2]}
    kw.update(ls_kwargs or {})
    ls = batch_ls(pose_t[win], pose[win], cmd_t, thrust_n, **kw)
    if not ls.converged:
        raise UserError(f"batch least squares on the first {ls_window_s:g} s did not converge "
                        f"({ls.message}); cannot start ls-ekf from it")
    if not np.all(np.isfinite(ls.cov)):
        bad = [lab for lab, v in zip(cfg.labels, np.diag(ls.cov), strict=True) if not np.isfinite(v)]
        raise UserError(f"the first {ls_window_s:g} s do not determine {', '.join(bad)} (infinite "
                        "variance); use a longer --ls-window")
    use = None if ls_start == "reuse" else ~win
    return run_ext_ekf(pose_t, pose, cmd_t, thrust_n, cfg, ls.z0, 0.5 * (ls.cov + ls.cov.T),
                       use=use), ls


def check_names(names: Sequence[str]) -> tuple[str, ...]:
    """Validate parameter names for the extended filter (raises ValueError)."""
    return ExtEkfConfig(names=tuple(names)).names

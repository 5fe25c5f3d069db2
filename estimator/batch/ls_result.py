"""The result of a batch least-squares fit (:class:`BatchResult`): the estimate, its
covariance with the measurement-noise and thrust-table parts, residuals and the JSON summary."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimator.plant.model import STATE_NAMES


@dataclass
class BatchResult:
    """Result of :func:`batch_ls` (SI units).

    Attributes:
        z0: (6+p,) estimate at ``t0``: x0, y0 (m), psi0 (rad), u0, v0 (m/s), r0 (rad/s),
            then the parameters in ``names`` order.
        cov: (6+p, 6+p) covariance ``Lambda^-1``; ``sigma`` its square-root diagonal.
        names: estimated parameters; ``params``: every model parameter used (estimated and fixed).
        mass_kg, izz_kgm2, mass_sigma_kg, izz_sigma_kgm2, corr_mass_izz: convenience
            copies (sigma 0 and correlation NaN for a fixed parameter).
        t: (N,) pose times; residuals: (N, 3) measured minus predicted pose (yaw wrapped).
        iterations: accepted Gauss-Newton steps over all stages; converged: the last
            correction was below ``tol``; cost_history: cost after every accepted step
            (the first entry is the initial cost of each stage); stages: horizon of each stage, s.
    """

    z0: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    names: tuple[str, ...]
    params: dict[str, float]
    t0: float
    t: np.ndarray
    residuals: np.ndarray
    iterations: int
    converged: bool
    cost_history: list[float]
    mass_kg: float
    izz_kgm2: float
    mass_sigma_kg: float
    izz_sigma_kgm2: float
    corr_mass_izz: float
    message: str = ""
    stages: list[float] = field(default_factory=list)
    elapsed_s: float = 0.0
    fisher: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)
    cov_noise: np.ndarray | None = None
    cov_thrust: np.ndarray | None = None
    thrust_terms: tuple[str, ...] = ()
    thrust_note: str = ""
    reference: tuple | None = field(default=None, repr=False, compare=False)
    """``(grid, states, pose_t, max_step, z0, params)``: the fit's segment grid and reference
    trajectory at ``z0`` with ``params`` (:func:`estimator.batch.consider.batch_consider`
    reuses them instead of integrating the same trajectory again); None when not kept."""

    def add_thrust_covariance(self, cov_thrust: np.ndarray, terms: tuple[str, ...]) -> None:
        """Make ``cov``/``sigma`` (and the mass/Izz copies) the TOTAL: measurement noise
        plus the thrust table's consider part ``cov_thrust`` (:mod:`estimator.batch.consider`)."""
        if self.cov_noise is None:
            self.cov_noise = self.cov
        self.cov_thrust = cov_thrust
        self.thrust_terms = tuple(terms)
        self.cov = self.cov_noise + cov_thrust
        self.sigma = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        for name, attr in (("mass", "mass_sigma_kg"), ("izz", "izz_sigma_kgm2")):
            if name in self.names:
                setattr(self, attr, float(self.sigma[6 + self.names.index(name)]))
        if "mass" in self.names and "izz" in self.names:
            im, ii = 6 + self.names.index("mass"), 6 + self.names.index("izz")
            self.corr_mass_izz = float(self.cov[im, ii] / (self.sigma[im] * self.sigma[ii]))

    @property
    def sigma_noise(self) -> np.ndarray:
        """(6+p,) standard deviations from measurement noise alone."""
        c = self.cov if self.cov_noise is None else self.cov_noise
        return np.sqrt(np.maximum(np.diag(c), 0.0))

    @property
    def sigma_thrust(self) -> np.ndarray:
        """(6+p,) standard deviations from the thrust table's uncertainty (0 without one)."""
        if self.cov_thrust is None:
            return np.zeros(len(self.z0))
        return np.sqrt(np.maximum(np.diag(self.cov_thrust), 0.0))

    def budget(self) -> dict[str, tuple[float, float, float]]:
        """``{parameter: (sigma_noise, sigma_thrust, sigma_total)}`` in SI units."""
        sn, st, s = self.sigma_noise, self.sigma_thrust, self.sigma
        return {n: (float(sn[6 + j]), float(st[6 + j]), float(s[6 + j]))
                for j, n in enumerate(self.names)}

    @property
    def labels(self) -> tuple[str, ...]:
        return STATE_NAMES + self.names

    def rms_residuals(self) -> np.ndarray:
        """(3,) RMS of the x, y (m) and yaw (rad) residuals."""
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no per-pose arrays)."""
        with np.errstate(invalid="ignore"):  # inf / inf for a direction without information
            corr = self.cov / np.outer(np.where(self.sigma > 0, self.sigma, 1),
                                       np.where(self.sigma > 0, self.sigma, 1))
        return {
            "mass_kg": self.mass_kg, "mass_sigma_kg": self.mass_sigma_kg,
            "izz_kgm2": self.izz_kgm2, "izz_sigma_kgm2": self.izz_sigma_kgm2,
            "corr_mass_izz": None if math.isnan(self.corr_mass_izz) else self.corr_mass_izz,
            "converged": self.converged, "iterations": self.iterations,
            "estimated": list(self.names), "params": self.params,
            "z0": dict(zip(self.labels, self.z0.tolist(), strict=True)),
            "sigma": dict(zip(self.labels, self.sigma.tolist(), strict=True)),
            "correlation": corr.tolist(),
            "t0_s": self.t0, "n_poses": int(len(self.t)),
            "rms_residual_x_m": float(self.rms_residuals()[0]),
            "rms_residual_y_m": float(self.rms_residuals()[1]),
            "rms_residual_yaw_rad": float(self.rms_residuals()[2]),
            "final_cost": self.cost_history[-1] if self.cost_history else None,
            "cost_history": self.cost_history, "stages_s": self.stages,
            "message": self.message, "elapsed_s": self.elapsed_s,
            **self._budget_dict(),
            **({"warnings": list(self.warnings)} if self.warnings else {}),
        }

    def _budget_dict(self) -> dict[str, Any]:
        """The uncertainty budget keys of :meth:`to_dict` (sigma = total; RSS of the parts)."""
        sn, st = self.sigma_noise, self.sigma_thrust
        out: dict[str, Any] = {}
        for name, unit in (("mass", "kg"), ("izz", "kgm2")):
            if name in self.names:
                i = 6 + self.names.index(name)
                out[f"{name}_sigma_noise_{unit}"] = float(sn[i])
                out[f"{name}_sigma_thrust_{unit}"] = float(st[i])
        out["sigma_noise"] = dict(zip(self.labels, sn.tolist(), strict=True))
        out["sigma_thrust"] = dict(zip(self.labels, st.tolist(), strict=True))
        out["thrust_uncertainty"] = {"included": self.cov_thrust is not None,
                                     "terms": list(self.thrust_terms),
                                     "note": self.thrust_note}
        return out

"""The result of an in-situ thrust calibration (:class:`ThrustCalibrationResult`): the
factors, their uncertainty budget (noise, known mass and Izz, the table's own), the new
table with them, and the JSON summary."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from common.thrust_table import ThrustTable
from estimator.batch.thrust_factors import (
    N_CHANNELS,
    channel_name,
    remaining_uncertainty,
    with_factors,
)


@dataclass
class ThrustCalibrationResult:
    """In-situ factors of a thrust table (dimensionless) with their uncertainty budget.

    Attributes:
        names: (P,) estimated factors (``efficiency.J``, ``nozzle_scale.K``).
        values: (P,) their estimates.
        cov: (P, P) total covariance = cov_noise + cov_mass + cov_izz + cov_table.
        cov_noise, cov_mass, cov_izz, cov_table: (P, P) the parts (measurement noise; the
            known mass's and Izz's uncertainty; the table's own stated uncertainty).
        table_terms: names of the table parameters carried in ``cov_table``.
        absorbed: table uncertainty terms the factors calibrate away (``scale``, ``scale.k``).
        reference_count: ``both``: the nozzle count whose scale stays fixed (else None).
        state0: (6,) initial state x, y (m), psi (rad), u, v (m/s), r (rad/s) at ``t0``.
        extras: estimated model parameters (ct, cr, kb, ax, ay; SI) with ``extras_sigma``.
        residuals: (N, 3) pose minus prediction (m, m, rad).
        min_eigenvalue: of the unit-diagonal factor information (1 = uncorrelated factors).
        correlation: (P, P) of the total covariance.
        izz: Izz estimated with the factors (only the mass known; :func:`izz_estimate`),
            else None.
    """

    names: tuple[str, ...]
    values: np.ndarray
    cov: np.ndarray
    cov_noise: np.ndarray
    cov_mass: np.ndarray
    cov_izz: np.ndarray
    cov_table: np.ndarray
    table_terms: tuple[str, ...]
    absorbed: tuple[str, ...]
    reference_count: int | None
    per: str
    model: str
    state0: np.ndarray
    extras: dict[str, float]
    extras_sigma: dict[str, float]
    t0: float
    t: np.ndarray
    residuals: np.ndarray
    iterations: int
    converged: bool
    stages: list[float]
    min_eigenvalue: float
    known: dict[str, float]
    kept_cross: np.ndarray | None = None
    kept_names: tuple[str, ...] = ()
    warnings: list[str] = field(default_factory=list)
    izz: dict[str, Any] | None = None
    misfit: dict[str, Any] | None = None  # misfit statistics (its warnings are in warnings)

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    @property
    def correlation(self) -> np.ndarray:
        s = np.where(self.sigma > 0, self.sigma, 1.0)
        return self.cov / np.outer(s, s)

    def budget(self) -> dict[str, dict[str, float]]:
        """``{factor: {"noise", "mass", "izz", "table", "total"}}`` 1-sigma parts; their
        root-sum-square is the total."""
        out = {}
        for i, n in enumerate(self.names):
            parts = {k: float(math.sqrt(max(c[i, i], 0.0))) for k, c in
                     (("noise", self.cov_noise), ("mass", self.cov_mass), ("izz", self.cov_izz),
                      ("table", self.cov_table))}
            parts["total"] = float(self.sigma[i])
            out[n] = parts
        return out

    def limited_by(self) -> dict[str, str]:
        """The largest part of each factor's variance, in words."""
        words = {"noise": "measurement noise", "mass": "known mass uncertainty",
                 "izz": "known Izz uncertainty", "table": "thrust table uncertainty"}
        return {n: words[max(("noise", "mass", "izz", "table"), key=lambda k: b[k])]
                for n, b in self.budget().items()}

    def rms_residuals(self) -> np.ndarray:
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    def new_table(self, table: ThrustTable, *, source: str = "tpods calibrate thrust",
                  run: str = "") -> ThrustTable:
        """``table`` with the factors and their covariance in ``[calibration]`` (original
        coefficients kept; absorbed ``[uncertainty]`` terms removed)."""
        names = list(self.names) + list(self.kept_names)
        P, K = len(self.names), len(self.kept_names)
        cov = np.zeros((P + K, P + K))
        cov[:P, :P] = self.cov
        if K:
            kept_cov = kept_covariance(table, self.kept_names)
            cov[P:, P:] = kept_cov
            cov[:P, P:] = self.kept_cross
            cov[P:, :P] = self.kept_cross.T
        cov = 0.5 * (cov + cov.T)
        notes = []
        if self.reference_count is not None:
            notes.append(f"nozzle_scale.{self.reference_count} held fixed (reference count): "
                         "the efficiencies carry the common level, the other counts' scales "
                         "are relative to it")
        if self.absorbed:
            notes.append("calibrated away: " + ", ".join(self.absorbed))
        if "scale" in self.names:  # a common scale: written as equal efficiencies
            names, cov = scale_as_efficiencies(table, names, self.values, cov)
            notes.append("--per common: one scale of every thrust, written as the "
                         "efficiencies (fully correlated)")
        info = {"source": source, **({"run": run} if run else {}),
                "known": {**self.known, "per": self.per, "model": self.model,
                          **({"izz_estimated_kgm2": self.izz["izz_kgm2"],
                              "izz_estimated_sigma_kgm2": self.izz["izz_sigma_kgm2"]}
                             if self.izz is not None else {})},
                **({"notes": "; ".join(notes)} if notes else {})}
        new = with_factors(table, self.names, self.values, parameters=names, covariance=cov,
                           info=info)
        return replace(new, uncertainty=remaining_uncertainty(table.uncertainty, self.absorbed))

    def to_dict(self) -> dict[str, Any]:
        b = self.budget()
        lim = self.limited_by()
        rms = self.rms_residuals()
        return {
            "per": self.per, "model": self.model,
            "factors": {n: {"value": float(v), "sigma": b[n]["total"],
                            "sigma_noise": b[n]["noise"], "sigma_mass": b[n]["mass"],
                            "sigma_izz": b[n]["izz"], "sigma_table": b[n]["table"],
                            "limited_by": lim[n]}
                        for n, v in zip(self.names, self.values, strict=True)},
            "parameters": list(self.names),
            "covariance": self.cov.tolist(),
            "correlation": self.correlation.tolist(),
            "reference_count": self.reference_count,
            "absorbed_table_terms": list(self.absorbed),
            "table_terms": list(self.table_terms),
            "known": dict(self.known),
            "state0": dict(zip(("x", "y", "psi", "u", "v", "r"), self.state0.tolist(), strict=True)),
            "extras": dict(self.extras), "extras_sigma": dict(self.extras_sigma),
            "t0_s": self.t0, "n_poses": int(len(self.t)),
            "rms_residual_x_m": float(rms[0]), "rms_residual_y_m": float(rms[1]),
            "rms_residual_yaw_rad": float(rms[2]),
            "iterations": self.iterations, "converged": self.converged,
            "stages_s": list(self.stages), "min_eigenvalue": self.min_eigenvalue,
            **(self.izz if self.izz is not None else {}),
            **({"warnings": list(self.warnings)} if self.warnings else {}),
        }


def scale_as_efficiencies(table: ThrustTable, names: Sequence[str], values: np.ndarray,
                          cov: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Parameters and covariance of a table calibrated with a common ``scale`` (first of
    ``names``; the others kept from the table): ``efficiency.J = scale * e_J`` for every
    channel, ``e_J`` the table's efficiency (or the kept one), the rest unchanged."""
    eff = table.channel_factors(N_CHANNELS)
    s = float(values[0])
    kept = list(names[1:])
    out = [channel_name(j) for j in range(len(eff))] + [n for n in kept if n not in
                                                        {channel_name(j) for j in range(len(eff))}]
    J = np.zeros((len(out), len(names)))
    for r, n in enumerate(out):
        if r < len(eff):
            J[r, 0] = eff[r]
            if n in kept:
                J[r, 1 + kept.index(n)] = s
        else:
            J[r, 1 + kept.index(n)] = 1.0
    C = J @ cov @ J.T
    return out, 0.5 * (C + C.T)


def izz_estimate(izz_kgm2: float, rows: dict[str, np.ndarray], names: Sequence[str],
                 factor_sigma: np.ndarray) -> dict[str, Any]:
    """The JSON keys of an Izz estimated with the factors ``names``: ``izz_kgm2``,
    ``izz_sigma_kgm2`` (total), its parts (``izz_sigma_noise_kgm2``, ``izz_sigma_mass_kgm2``,
    ``izz_sigma_table_kgm2``) and ``izz_correlation`` with each factor (total covariance).
    ``rows``: ``{part: (1, P+1) row of Izz in that part's covariance over (factors, Izz)}``;
    ``factor_sigma``: (P,) the factors' total sigma."""
    P = len(names)
    total = sum(r[0] for r in rows.values())
    sig = math.sqrt(max(float(total[P]), 0.0))
    den = sig * np.asarray(factor_sigma, float)
    corr = np.divide(total[:P], den, out=np.zeros(P), where=den > 0)
    return {"izz_kgm2": izz_kgm2, "izz_sigma_kgm2": sig,
            **{f"izz_sigma_{k}_kgm2": math.sqrt(max(float(r[0, P]), 0.0))
               for k, r in rows.items() if k != "izz"},
            "izz_correlation": {n: float(c) for n, c in zip(names, corr, strict=True)}}


def kept_covariance(table: ThrustTable, kept: Sequence[str]) -> np.ndarray:
    cal = table.calibration
    idx = [cal.parameters.index(n) for n in kept]
    return cal.covariance[np.ix_(idx, idx)]

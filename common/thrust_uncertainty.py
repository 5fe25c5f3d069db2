"""What a thrust table does not know: its uncertainty, and factors calibrated in situ.

A thrust table (:mod:`common.thrust_table`) gives per-nozzle thrust as
``T_ij = eff_j * nscale_k * poly_k(D_ij)`` for channel ``j`` in a command row ``i`` with
``k`` open nozzles. Its uncertainty has up to four parts, each optional:

- ``[fit.nozzles.k] covariance``: the covariance of the row's coefficients (ascending
  powers, the table's unit squared), as ``tpods bench fit`` writes it. Statistical.
- ``[uncertainty] scale_rel``: a relative 1-sigma scale error common to every nozzle and
  nozzle count (balance calibration and linearity, pressure set-point, PWM frequency
  differences between bench and run). ``[uncertainty.nozzles.k] scale_rel``: the same for
  one nozzle count only (its accumulator and regulator). ``source`` keys say how a value
  was obtained (free text, kept).
- ``[calibration]``: factors estimated in situ (``tpods calibrate thrust``): ``efficiency``
  (one per channel, default 1) and ``nozzle_scale`` (``{"k" = factor}``, default 1), with
  ``covariance`` over the names in ``parameters`` (``"efficiency.1"``, ...,
  ``"nozzle_scale.2"``).

:func:`thrust_sensitivity` turns a table and duty rows into thrusts and their derivatives
with respect to every uncertain parameter, with the parameters' covariance: the input of
the consider covariance (:mod:`estimator.batch.consider`). Units: thrusts in N, scale
terms relative (dimensionless), coefficients in the table's unit.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.errors import UserError

UNCERTAINTY_KEYS = ("scale_rel", "source", "nozzles", "notes")
CALIBRATION_KEYS = ("efficiency", "nozzle_scale", "parameters", "covariance", "source",
                    "run", "notes", "known")


def _num(x: Any, what: str) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise UserError(f"{what} must be a number, got {x!r}")
    v = float(x)
    if not math.isfinite(v):
        raise UserError(f"{what} must be finite, got {x!r}")
    return v


def _unknown(keys, valid: Sequence[str], where: str) -> None:
    for key in keys:
        if key not in valid:
            near = difflib.get_close_matches(key, valid, n=1, cutoff=0.6)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise UserError(f"{where}: unknown key {key!r}{hint}; valid: {', '.join(valid)}")


def _covariance(rows: Any, n: int, what: str) -> np.ndarray:
    """A symmetric positive semi-definite (n, n) matrix from nested lists, or UserError."""
    try:
        C = np.array([[_num(x, what) for x in row] for row in rows], dtype=float)
    except TypeError:
        raise UserError(f"{what} must be a list of {n} rows of {n} numbers") from None
    if C.shape != (n, n):
        raise UserError(f"{what} must be {n} x {n}, got {'x'.join(map(str, C.shape))}")
    scale = max(float(np.max(np.abs(C))), 1e-300)
    if not np.allclose(C, C.T, rtol=1e-6, atol=1e-9 * scale):
        raise UserError(f"{what} is not symmetric")
    C = 0.5 * (C + C.T)
    if n and float(np.min(np.linalg.eigvalsh(C))) < -1e-8 * scale:
        raise UserError(f"{what} is not positive semi-definite (a variance cannot be negative)")
    return C


@dataclass(frozen=True)
class ThrustUncertainty:
    """``[uncertainty]``: relative 1-sigma scale errors (dimensionless).

    Attributes:
        scale_rel: common to every nozzle and nozzle count.
        nozzle_scale_rel: ``{k: sigma}`` for one nozzle count only.
        sources: ``{"scale_rel": how it was obtained, "nozzles.k": ...}``.
    """

    scale_rel: float = 0.0
    nozzle_scale_rel: Mapping[int, float] = field(default_factory=dict)
    sources: Mapping[str, str] = field(default_factory=dict)
    notes: str = ""

    @classmethod
    def from_dict(cls, data: Any) -> ThrustUncertainty:
        if not isinstance(data, Mapping):
            raise UserError("[uncertainty] must be a table")
        _unknown(data, UNCERTAINTY_KEYS, "[uncertainty]")
        scale = _num(data.get("scale_rel", 0.0), "[uncertainty] scale_rel")
        if scale < 0:
            raise UserError(f"[uncertainty] scale_rel must be >= 0, got {scale:g}")
        sources = {}
        if "source" in data:
            sources["scale_rel"] = str(data["source"])
        per: dict[int, float] = {}
        nozzles = data.get("nozzles", {})
        if not isinstance(nozzles, Mapping):
            raise UserError("[uncertainty] nozzles must be tables [uncertainty.nozzles.k]")
        for k, v in nozzles.items():
            where = f"[uncertainty.nozzles.{k}]"
            try:
                kk = int(k)
            except ValueError:
                raise UserError(f"{where}: the nozzle count must be an integer") from None
            if not isinstance(v, Mapping):
                raise UserError(f"{where} must be a table")
            _unknown(v, ("scale_rel", "source"), where)
            s = _num(v.get("scale_rel", 0.0), f"{where} scale_rel")
            if s < 0:
                raise UserError(f"{where} scale_rel must be >= 0, got {s:g}")
            per[kk] = s
            if "source" in v:
                sources[f"nozzles.{kk}"] = str(v["source"])
        return cls(scale, per, sources, str(data.get("notes", "")))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"scale_rel": float(self.scale_rel)}
        if "scale_rel" in self.sources:
            out["source"] = self.sources["scale_rel"]
        if self.notes:
            out["notes"] = self.notes
        if self.nozzle_scale_rel:
            out["nozzles"] = {}
            for k in sorted(self.nozzle_scale_rel):
                row: dict[str, Any] = {"scale_rel": float(self.nozzle_scale_rel[k])}
                if f"nozzles.{k}" in self.sources:
                    row["source"] = self.sources[f"nozzles.{k}"]
                out["nozzles"][str(k)] = row
        return out


@dataclass(frozen=True)
class ThrustCalibration:
    """``[calibration]``: factors estimated on the assembled module (dimensionless).

    Attributes:
        efficiency: one factor per channel (thruster), multiplying its thrust.
        nozzle_scale: ``{k: factor}`` multiplying every nozzle's thrust when k are open.
        parameters: names of the covariance's rows (``efficiency.J``, ``nozzle_scale.K``).
        covariance: (P, P) covariance of those factors.
        info: the other keys (source, run, known values), kept as written.
    """

    efficiency: tuple[float, ...] = ()
    nozzle_scale: Mapping[int, float] = field(default_factory=dict)
    parameters: tuple[str, ...] = ()
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    info: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, data: Any) -> ThrustCalibration:
        if not isinstance(data, Mapping):
            raise UserError("[calibration] must be a table")
        _unknown(data, CALIBRATION_KEYS, "[calibration]")
        eff = tuple(_num(x, "[calibration] efficiency") for x in data.get("efficiency", ()))
        if any(e <= 0 for e in eff):
            raise UserError(f"[calibration] efficiency factors must be positive, got {list(eff)}")
        ns_raw = data.get("nozzle_scale", {})
        if not isinstance(ns_raw, Mapping):
            raise UserError('[calibration] nozzle_scale must be a table {"1" = factor, ...}')
        ns = {}
        for k, v in ns_raw.items():
            try:
                kk = int(k)
            except ValueError:
                raise UserError(f"[calibration] nozzle_scale: {k!r} is not a nozzle count") from None
            ns[kk] = _num(v, f"[calibration] nozzle_scale.{k}")
            if ns[kk] <= 0:
                raise UserError(f"[calibration] nozzle_scale.{k} must be positive")
        params = tuple(str(p) for p in data.get("parameters", ()))
        valid = {f"efficiency.{j + 1}" for j in range(len(eff))} | {f"nozzle_scale.{k}" for k in ns}
        bad = [p for p in params if p not in valid]
        if bad:
            raise UserError(f"[calibration] parameters: {', '.join(bad)} name no factor of the "
                            f"table (valid: {', '.join(sorted(valid))})")
        if "covariance" in data:
            cov = _covariance(data["covariance"], len(params), "[calibration] covariance")
        elif params:
            raise UserError("[calibration] parameters given without a covariance")
        else:
            cov = np.zeros((0, 0))
        info = {k: v for k, v in data.items()
                if k not in ("efficiency", "nozzle_scale", "parameters", "covariance")}
        return cls(eff, ns, params, cov, info)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self.info)
        if self.efficiency:
            out["efficiency"] = [float(e) for e in self.efficiency]
        if self.nozzle_scale:
            out["nozzle_scale"] = {str(k): float(v) for k, v in sorted(self.nozzle_scale.items())}
        if self.parameters:
            out["parameters"] = list(self.parameters)
            out["covariance"] = [[float(x) for x in row] for row in self.covariance]
        return out

    def factors(self, n_channels: int) -> np.ndarray:
        """(n_channels,) efficiency per channel (1 where none is given)."""
        f = np.ones(n_channels)
        m = min(n_channels, len(self.efficiency))
        f[:m] = self.efficiency[:m]
        return f


def coefficient_covariance(extra: Mapping[str, Any], k: int, n_coef: int) -> np.ndarray | None:
    """The ``[fit.nozzles.k] covariance`` of a table's ``extra`` keys, or None."""
    fit = extra.get("fit")
    if not isinstance(fit, Mapping):
        return None
    rows = fit.get("nozzles", {})
    row = rows.get(str(k)) if isinstance(rows, Mapping) else None
    if not isinstance(row, Mapping) or "covariance" not in row:
        return None
    return _covariance(row["covariance"], n_coef, f"[fit.nozzles.{k}] covariance")


@dataclass(frozen=True)
class ThrustSensitivity:
    """Thrusts and their derivatives with respect to a table's uncertain parameters.

    Attributes:
        thrust_n: (..., C) thrust per channel, N.
        jacobian: (..., C, P) d thrust_n / d parameter (N per unit of the parameter).
        names: (P,) parameter names: ``scale``, ``scale.k``, ``coef.k.p`` (table unit),
            ``efficiency.j``, ``nozzle_scale.k``.
        covariance: (P, P) the parameters' covariance (the table's statement).
    """

    thrust_n: np.ndarray
    jacobian: np.ndarray
    names: tuple[str, ...]
    covariance: np.ndarray

    @property
    def empty(self) -> bool:
        """True when the table states no uncertainty (or none that reaches these rows)."""
        return len(self.names) == 0


def factor_derivative(table, thrust: np.ndarray, open_count: np.ndarray, eff: Sequence[float],
                      name: str) -> np.ndarray:
    """Derivative of the thrusts ``(..., C)`` (N) with respect to the in-situ factor ``name``
    of ``table`` (N per unit factor): ``T_j / eff_j`` in channel j for ``efficiency.J``,
    ``T / nozzle_scale_K`` on the rows with K nozzles open (``open_count``) for
    ``nozzle_scale.K``; ``eff`` the table's channel efficiencies."""
    kind, idx = name.split(".")
    if kind == "efficiency":
        j = int(idx) - 1
        col = np.zeros_like(thrust)
        col[..., j] = thrust[..., j] / eff[j]
        return col
    kk = int(idx)
    return np.where((open_count == kk)[..., None], thrust / table.nozzle_factor(kk), 0.0)


def thrust_sensitivity(table, duty_pct: np.ndarray, clamp: bool = False) -> ThrustSensitivity:
    """Thrusts of ``duty_pct`` rows (..., C) and their derivatives with respect to every
    uncertain parameter ``table`` states (see the module doc). A parameter whose rows
    never occur (a nozzle count never used) is left out."""
    thrust = table.thrust_n(duty_pct, clamp=clamp)
    d = np.asarray(duty_pct, dtype=float)
    lo, hi = table.duty_range
    is_open = d > 0
    if clamp:
        d = np.where(is_open, np.clip(d, lo, hi), 0.0)
    k = is_open.sum(axis=-1)
    live = thrust > 0  # a clipped (zero) thrust does not move with the parameters
    cols: list[np.ndarray] = []
    names: list[str] = []
    blocks: list[np.ndarray] = []
    unc = table.uncertainty
    if unc is not None and unc.scale_rel > 0:
        cols.append(thrust)
        names.append("scale")
        blocks.append(np.array([[unc.scale_rel**2]]))
    if unc is not None:
        for kk, s in sorted(unc.nozzle_scale_rel.items()):
            rows = (k == kk)[..., None]
            if s > 0 and np.any(rows & live):
                cols.append(np.where(rows, thrust, 0.0))
                names.append(f"scale.{kk}")
                blocks.append(np.array([[s * s]]))
    to_n = table.newtons_per_unit
    eff = table.channel_factors(d.shape[-1])
    for kk in sorted(table.coefficients):
        cov = coefficient_covariance(table.extra, kk, len(table.coefficients[kk]))
        rows = (k == kk)[..., None] & live
        if cov is None or not np.any(rows):
            continue
        gain = eff * table.nozzle_factor(kk) * to_n
        for p in range(len(table.coefficients[kk])):
            cols.append(np.where(rows, gain * d**p, 0.0))
            names.append(f"coef.{kk}.{p}")
        blocks.append(cov)
    cal = table.calibration
    if cal is not None and cal.parameters:
        for name in cal.parameters:
            cols.append(factor_derivative(table, thrust, k, eff, name))
            names.append(name)
        blocks.append(cal.covariance)
    P = len(names)
    jac = np.stack(cols, axis=-1) if cols else np.zeros(thrust.shape + (0,))
    cov = np.zeros((P, P))
    i = 0
    for b in blocks:
        n = len(b)
        cov[i:i + n, i:i + n] = b
        i += n
    return ThrustSensitivity(thrust, jac, tuple(names), cov)

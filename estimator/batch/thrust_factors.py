"""The in-situ factors of a thrust table (channel efficiencies, nozzle-count scales): which
ones a run can give (:func:`factor_names`), the table with given factors
(:func:`with_factors`), the thrusts' derivatives with respect to them
(:func:`factor_jacobian`) and the table uncertainty terms they absorb
(:func:`absorbed_terms`, :func:`remaining_uncertainty`). Used by
:mod:`estimator.batch.thrust_calibration.calibrate`.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from common.errors import UserError
from common.thrust_table import ThrustTable
from common.thrust_uncertainty import (
    ThrustCalibration,
    ThrustUncertainty,
    factor_derivative,
    thrust_sensitivity,
)

PER_CHOICES = ("thruster", "nozzles", "both", "common")
"""``common``: one factor ``scale`` multiplying every thrust (written into the table as equal
efficiencies with a fully correlated covariance)."""
MODEL_EXTRAS = {"ideal": (), "friction": ("ct", "cr", "kb"),
                "friction+tilt": ("ct", "cr", "kb", "ax", "ay")}
"""Nuisance parameters estimated beside the factors, per ``--model``."""

ABSORB_TOL = 1e-9
"""Relative residual below which a table term is exactly a combination of the factors."""

N_CHANNELS = 4


def channel_name(j: int) -> str:
    """``efficiency.J`` of 0-based channel ``j``."""
    return f"efficiency.{j + 1}"


def with_factors(table: ThrustTable, names: Sequence[str], values: Sequence[float], *,
                 parameters: Sequence[str] = (), covariance: np.ndarray | None = None,
                 info: Mapping[str, Any] | None = None) -> ThrustTable:
    """``table`` with the factors ``names`` set to ``values`` (other factors as the table
    has them) and a calibration covariance over ``parameters`` (default: none)."""
    cal = table.calibration
    eff = list(table.channel_factors(N_CHANNELS))
    ns = dict(cal.nozzle_scale) if cal is not None else {}
    for n, v in zip(names, values, strict=True):
        if n == "scale":
            continue
        kind, idx = n.split(".")
        if kind == "efficiency":
            eff[int(idx) - 1] = float(v)
        else:
            ns[int(idx)] = float(v)
    if "scale" in names:
        s = float(values[list(names).index("scale")])
        eff = [s * e for e in eff]
    cov = np.zeros((0, 0)) if covariance is None else np.asarray(covariance, float)
    new = ThrustCalibration(tuple(float(e) for e in eff), ns, tuple(parameters), cov,
                            dict(info) if info is not None else {})
    return replace(table, calibration=new)


def factor_jacobian(table: ThrustTable, duty_pct: np.ndarray, names: Sequence[str],
                    clamp: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Thrusts ``(..., 4)`` N and their derivatives ``(..., 4, P)`` with respect to the
    factors ``names`` (N per unit factor): ``T_j/eff_j`` in channel j, ``T/nozzle_scale_k``
    on rows with k open; ``T`` for ``scale`` (at scale 1: the table's factors as they are)."""
    thrust = table.thrust_n(duty_pct, clamp=clamp)
    k = (np.asarray(duty_pct) > 0).sum(axis=-1)
    eff = table.channel_factors(thrust.shape[-1])
    cols = [thrust if n == "scale" else factor_derivative(table, thrust, k, eff, n) for n in names]
    jac = np.stack(cols, axis=-1) if cols else np.zeros(thrust.shape + (0,))
    return thrust, jac


def factor_thrust(table: ThrustTable, duty_pct: np.ndarray, names: Sequence[str],
                  values: Sequence[float], clamp: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Thrusts ``(..., C)`` N with the factors ``names`` at ``values`` and their derivatives
    ``(..., C, P)``, the factors applied outside the table: a factor may be 0 or negative
    (a dead or reversed thruster), which the table itself (thrusts >= 0) cannot express.
    ``table`` holds the other factors; the estimated ones are taken as 1 in it."""
    unit = with_factors(table, names, np.ones(len(names))).thrust_n(duty_pct, clamp=clamp)
    d = np.asarray(duty_pct, float)
    k = (d > 0).sum(axis=-1)
    col = np.ones(unit.shape[-1])
    row = np.ones(unit.shape[:-1])
    scale = 1.0
    for n, v in zip(names, values, strict=True):
        if n == "scale":
            scale = float(v)
        elif n.startswith("efficiency."):
            col[int(n.split(".")[1]) - 1] = float(v)
        else:
            row = np.where(k == int(n.split(".")[1]), float(v), row)
    thrust = unit * col * row[..., None] * scale
    jac = np.zeros(unit.shape + (len(names),))
    for i, n in enumerate(names):
        if n == "scale":
            jac[..., i] = unit * col * row[..., None]
        elif n.startswith("efficiency."):
            j = int(n.split(".")[1]) - 1
            jac[..., j, i] = unit[..., j] * row * scale
        else:
            on = (k == int(n.split(".")[1]))[..., None]
            jac[..., i] = np.where(on, unit * col * scale, 0.0)
    return thrust, jac


def probe_rows(table: ThrustTable) -> np.ndarray:
    """(R, 4) duty rows covering every nozzle count of the table, every channel subset and
    duties across its valid range (for checks that must hold on any future run)."""
    lo, hi = table.duty_range
    levels = np.linspace(lo, hi, 4)
    rows = []
    for k in sorted(table.coefficients):
        if not 1 <= k <= N_CHANNELS:
            continue
        for sub in itertools.combinations(range(N_CHANNELS), k):
            for i, d in enumerate(levels):
                r = np.zeros(N_CHANNELS)
                r[list(sub)] = d
                rows.append(r)
                r2 = np.zeros(N_CHANNELS)
                r2[list(sub)] = levels[(i + np.arange(k)) % len(levels)]
                rows.append(r2)
    return np.array(rows)


def absorbed_terms(table: ThrustTable, names: Sequence[str]) -> tuple[str, ...]:
    """Table uncertainty terms (``scale``, ``scale.k``) that the factors ``names`` absorb
    exactly: on every duty row the table can be asked for, the term's thrust derivative
    is a fixed combination of the factors' derivatives, so a calibration shifts the
    factors by exactly the term's error and the calibrated thrust does not depend on it."""
    rows = probe_rows(table)
    base = with_factors(table, (), ())  # the factor values, no calibration covariance
    sens = thrust_sensitivity(base, rows)
    _, F = factor_jacobian(base, rows, names)
    A = F.reshape(-1, F.shape[-1])
    out = []
    for i, n in enumerate(sens.names):
        if not (n == "scale" or n.startswith("scale.")):
            continue
        b = sens.jacobian[..., i].reshape(-1)
        if A.shape[1] == 0:
            continue
        x = np.linalg.lstsq(A, b, rcond=None)[0]
        if np.linalg.norm(A @ x - b) <= ABSORB_TOL * max(np.linalg.norm(b), 1e-300):
            out.append(n)
    return tuple(out)


def remaining_uncertainty(unc: ThrustUncertainty | None, absorbed: Sequence[str]
                          ) -> ThrustUncertainty | None:
    """``unc`` without the absorbed terms (None when nothing is left and nothing was said)."""
    if unc is None:
        return None
    scale = 0.0 if "scale" in absorbed else unc.scale_rel
    per = {k: v for k, v in unc.nozzle_scale_rel.items() if f"scale.{k}" not in absorbed}
    sources = {k: v for k, v in unc.sources.items()
               if not (k == "scale_rel" and "scale" in absorbed)
               and not (k.startswith("nozzles.") and f"scale.{k.split('.')[1]}" in absorbed)}
    notes = unc.notes
    if absorbed:
        gone = ", ".join("scale_rel" if a == "scale" else f"nozzles.{a.split('.')[1]} scale_rel"
                         for a in absorbed)
        extra = f"calibrated away in situ (absorbed by [calibration]): {gone}"
        notes = f"{notes}; {extra}" if notes else extra
    return ThrustUncertainty(scale, per, sources, notes)


def counts_used(duty_pct: np.ndarray, cmd_t: np.ndarray, t_end: float) -> dict[int, float]:
    """``{k: seconds held}`` for every nozzle count k > 0 the commands hold before ``t_end``."""
    d = np.asarray(duty_pct)
    t = np.asarray(cmd_t, float)
    ends = np.append(t[1:], max(t_end, t[-1]))
    dur = np.clip(np.minimum(ends, t_end) - t, 0.0, None)
    k = (d > 0).sum(axis=-1)
    out: dict[int, float] = {}
    for kk in np.unique(k):
        if kk > 0:
            out[int(kk)] = float(dur[k == kk].sum())
    return {kk: v for kk, v in out.items() if v > 0}


def factor_names(per: str, duty_pct: np.ndarray, cmd_t: np.ndarray, t_end: float
                 ) -> tuple[tuple[str, ...], int | None]:
    """The factors ``per`` asks for on this run and the reference count (``both``), or a
    UserError for a run that cannot give them (no thrust; a thruster never opened)."""
    if per not in PER_CHOICES:
        raise UserError(f"--per must be one of {', '.join(PER_CHOICES)}, got {per!r}")
    used = counts_used(duty_pct, cmd_t, t_end)
    if not used:
        raise UserError("the run never opens a thruster: no thrust, nothing to calibrate")
    d = np.asarray(duty_pct)
    t = np.asarray(cmd_t, float)
    live = t < t_end
    names: list[str] = []
    if per == "common":
        return ("scale",), None
    n_channels = d.shape[-1]
    if per in ("thruster", "both"):
        never = [j + 1 for j in range(n_channels) if not np.any(d[live, j] > 0)]
        if never:
            which = ", ".join(str(j) for j in never)
            raise UserError(
                f"thruster{'s' if len(never) > 1 else ''} {which} {'is' if len(never) == 1 else 'are'} "
                f"never opened in this run: {'its efficiency' if len(never) == 1 else 'their efficiencies'} "
                "cannot be estimated (record a run that opens every thruster, e.g. "
                "translate-rotate or 'tpods design --for thrust-calibration', or use --per nozzles)")
        names += [channel_name(j) for j in range(n_channels)]
    ref = None
    if per in ("nozzles", "both"):
        ks = sorted(used)
        if per == "both" and len(ks) > 1:
            ref = max(ks, key=lambda kk: used[kk])
            ks = [kk for kk in ks if kk != ref]
        names += [f"nozzle_scale.{kk}" for kk in ks]
    return tuple(names), ref

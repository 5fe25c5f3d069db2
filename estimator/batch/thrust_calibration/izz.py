"""Izz estimated with the thrust factors: an in-situ calibration with only
the mass known.

With the mass m known, a run's translation gives the thrusts (``F = m a``) and so the
factors; its rotation gives torque over Izz, and with the thrusts known, Izz. Whether a run
separates them is read from the information on ``(factors, Izz)`` with the initial state
and the model's nuisance parameters marginalised out (:func:`check_identifiable`), Izz taken
relative (``d ln Izz``) so the same limits as the factors' apply:

- a run that never turns the body (no torque) gives no information on Izz;
- a run that turns it but whose net force does not fix the factors (pure couples; or per
  thruster, thrusters that only ever fire in pairs whose forces cancel) shows only
  ``torque / Izz``: Izz is confounded with the factors' level.

Either is refused, naming what is not identifiable and what would fix it (``--izz``, or a
run that both translates and turns the body).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from common.constants import PAPER_IZZ_KGM2, PAPER_MASS_KG
from common.errors import UserError
from estimator.batch.crlb import marginal_information
from estimator.batch.thrust_calibration.fit import (
    MAX_COMBINATION_SIGMA,
    MIN_EIGENVALUE,
    confounded,
    worst_combination,
)
from estimator.plant.model import wrench

START_GYRATION_M = math.sqrt(PAPER_IZZ_KGM2 / PAPER_MASS_KG)
"""Radius of gyration of the fallback start of an estimated Izz (the paper's module, 4.1 cm):
``m * START_GYRATION_M**2`` when the run gives no linear start (:func:`linear_start`)."""

IZZ = "Izz"

FIX = ("give --izz (e.g. from 'tpods calibrate bifilar'), or use a run that both translates "
       "and turns the body with varied thruster combinations (e.g. translate-rotate, or "
       "'tpods design --for thrust-calibration')")


def _double_integral(t: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``int_0^t int_0^s a`` at the times ``t`` (a (N, ...) held from each time on)."""
    dt = np.diff(t).reshape((-1,) + (1,) * (a.ndim - 1))
    rate = np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a[:-1] * dt, axis=0)])
    return np.concatenate([np.zeros((1,) + a.shape[1:]),
                           np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt, axis=0)])


def linear_start(pose_t, pose, cmd_t, factor_jac, mass_kg: float, arm_m: float
                 ) -> tuple[np.ndarray | None, float | None]:
    """A start for the factors and Izz by linear least squares, without damping: the thrust
    is ``sum_i f_i J_i`` (``factor_jac`` (Nc, 4, P) at unit factors), so with the measured
    yaw turning the body force into the table frame the positions are linear in ``f``
    (``m`` known) and then the yaw in ``1/Izz``. ``(f or None, Izz or None)``: None where the
    run gives no finite (positive, for Izz) answer; the growing horizon refines both."""
    t = np.asarray(pose_t, float) - float(pose_t[0])
    pose = np.asarray(pose, float)
    yaw = np.unwrap(pose[:, 2])
    idx = np.clip(np.searchsorted(cmd_t, pose_t, side="right") - 1, 0, len(cmd_t) - 1)
    w = wrench(np.moveaxis(np.asarray(factor_jac, float)[idx], -1, -2), arm_m)  # (N, P, 3)
    c, sn = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    fx = c * w[..., 0] - sn * w[..., 1]
    fy = sn * w[..., 0] + c * w[..., 1]
    Bx, By, A = (_double_integral(t, q) for q in (fx / mass_kg, fy / mass_kg, w[..., 2]))
    one, zero = np.ones_like(t), np.zeros_like(t)
    X = np.vstack([np.column_stack([one, t, zero, zero, Bx]),
                   np.column_stack([zero, zero, one, t, By])])
    with np.errstate(all="ignore"):
        f = np.linalg.lstsq(X, np.concatenate([pose[:, 0], pose[:, 1]]), rcond=None)[0][4:]
    if not np.all(np.isfinite(f)) or not np.any(f):
        return None, None
    torque = A @ f
    if not np.any(torque):
        return f, None
    b = np.linalg.lstsq(np.column_stack([one, t, torque]), yaw, rcond=None)[0][2]
    return f, (float(1.0 / b) if math.isfinite(b) and b > 0 else None)


def izz_start(mass_kg: float, izz0_kgm2: float | None = None, yaw_start: float | None = None
              ) -> float:
    """The start of an estimated Izz, kg m^2: ``izz0_kgm2``, else the linear one
    (:func:`linear_start`), else ``m * START_GYRATION_M**2``."""
    if izz0_kgm2:
        return float(izz0_kgm2)
    return float(yaw_start) if yaw_start else float(mass_kg) * START_GYRATION_M**2


def joint_information(Lam: np.ndarray, i_izz: int, ne: int, izz_kgm2: float) -> np.ndarray:
    """Information on ``(factors..., ln Izz)`` from the full information ``Lam`` over
    ``(s0, extras (Izz at i_izz), factors)``, the other parameters marginalised."""
    n = len(Lam)
    order = [i for i in range(ne) if i != i_izz] + list(range(ne, n)) + [i_izz]
    L = Lam[np.ix_(order, order)].copy()
    L[-1, :] *= izz_kgm2
    L[:, -1] *= izz_kgm2
    return marginal_information(L, ne - 1)


def check_identifiable(Lam: np.ndarray, i_izz: int, ne: int, names: Sequence[str],
                       izz_kgm2: float) -> float:
    """Raise :class:`UserError` when the run does not inform Izz together with the factors
    ``names``; return the smallest eigenvalue of the equilibrated joint information."""
    M = joint_information(Lam, i_izz, ne, izz_kgm2)
    labels = (*names, IZZ)
    lam_min, which = confounded(M, labels)
    sigma = None
    if lam_min >= MIN_EIGENVALUE:
        sigma, which = worst_combination(M, labels)
        if sigma <= MAX_COMBINATION_SIGMA:
            return lam_min
    if IZZ not in which:
        return lam_min  # the factors alone: the factor check names them
    if M[-1, -1] <= 0 or (which == (IZZ,) and _no_torque(M)):
        raise UserError(f"Izz is not identifiable from this run: it never turns the body (no "
                        f"torque, no information on Izz); {FIX}")
    others = [n for n in which if n != IZZ]
    why = (f"smallest eigenvalue of the equilibrated information {lam_min:.2g} < {MIN_EIGENVALUE:g}"
           if sigma is None else
           f"their least determined combination has sigma {sigma:.2g} > {MAX_COMBINATION_SIGMA:g}")
    if not others:
        raise UserError(f"Izz is hardly identifiable from this run: it turns the body too little "
                        f"({why}); {FIX}")
    raise UserError(f"Izz and {', '.join(others)} are not identifiable together from this run: "
                    f"its rotation shows only torque / Izz and its net force does not fix the "
                    f"thrust ({why}); {FIX}")


def _no_torque(M: np.ndarray) -> bool:
    """True when Izz's information is negligible beside the factors' (relative units)."""
    d = np.abs(np.diag(M))
    return bool(d[-1] <= 1e-12 * max(float(d[:-1].max(initial=0.0)), 1e-300))
